"""Peer scanners: the multi-shot structured-light methods nurbscan's single shot is compared
with, rendered through the same simulator and triangulated with the same rig.

* :mod:`.graycode` -- OpenCV's Gray code (column resolution, no phase shift; issue 9).
* :mod:`.phaseshift` -- N-step phase shifting unwrapped by complementary Gray code
  (sub-pixel projector coordinates in both directions; issue 37).
"""
