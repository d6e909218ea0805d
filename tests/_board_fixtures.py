"""Shared helper of tests/test_simulate.py and tests/test_calibrate.py: a free chessboard pose.

The simulator's free calibration pose ``k`` (:func:`nurbscan.simulate.target.free_board_poses`,
aimed at the turntable's axis) as a renderable scene in the object frame at table angle 0, the
same placement :func:`nurbscan.simulate.scan.simulate_scan` renders.
"""

from __future__ import annotations

import numpy as np

from nurbscan.simulate.target import BoardScene, Chessboard, free_board_poses


def free_board(rig, k: int, board: Chessboard | None = None):
    """``(board, scene, R, T)``: free pose ``k`` of ``board`` (default chessboard) as a
    :class:`BoardScene` and its board -> rig pose (X_rig = R P + T, mm)."""
    board = board or Chessboard()
    aim = np.asarray(rig.turntable.to_rig(np.zeros((1, 3)), 0.0))[0] * [0, 0, 1]
    r_b, t_b = free_board_poses(board, aim)[k]
    m = np.asarray(rig.turntable.to_rig(np.vstack([np.zeros(3), np.eye(3)]), 0.0))
    mm, tt = (m[1:] - m[0]).T, m[0]
    return board, BoardScene(board, mm.T @ r_b, mm.T @ (t_b - tt)), r_b, t_b
