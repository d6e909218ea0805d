"""What the decoded points of the shared real set allow the projector calibration (issue 31).

Measures, on the shared real projector-camera set (``benchmarks/real_procam.py``; skipped when
it is absent), with the calibration of poses 1-8 (300 points a pose, the white part's shape
fitted, as ``bench_real_calibrate``):

* OpenCV's own ``calibrateCamera`` (projector as an inverse camera; 4 and 8 distortion terms,
  its own board poses) on the decoded grid crossings of the white part: their board points
  on the corners' plane, and on the fitted white-part surface (``x, y, h(x, y)``); the
  second is the best point set this detector gives;
* the residuals of all decoded centre-line points of the white part under that calibration:
  their RMS, the RMS of each line piece's mean (what a free offset per line could remove)
  and the scatter about it along each line, with its correlation at lags of 1-16 camera px;
* the source project's own grid nodes (``reference/calibration.yml``, read here as an
  oracle only) calibrated by OpenCV on the plane of their camera poses, without the free
  3-D node positions of their bundle (their published 0.238 px 2-D comes with those).

Usage: ``python benchmarks/real_projector_bound.py`` (prints the figures).
"""

from __future__ import annotations

import importlib.util
import sys
import tempfile
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def _load(name: str):
    spec = importlib.util.spec_from_file_location(name, HERE / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def opencv_on_crossings(res, cache: dict) -> dict:
    """OpenCV calibrateCamera RMS (2-D and per coordinate) on the white part's crossings."""
    import cv2

    from nurbscan.calibrate.board import outside_field
    from nurbscan.calibrate.surface import surface_points

    keys = sorted(cache, key=lambda k: k[0])
    dc = tuple(res.figures["pixel_pitch_mm"]["camera"])
    dp = tuple(res.figures["pixel_pitch_mm"]["projector"])
    flat, shaped, img = [], [], []
    for i, k in enumerate(keys):
        _, _, det, area = cache[k]
        cam, prj = np.asarray(det.cam, float), np.asarray(det.proj, float)
        ij = np.clip(np.round(cam).astype(int), 0, [area.shape[1] - 1, area.shape[0] - 1])
        m = area[ij[:, 1], ij[:, 0]]
        cam, prj = cam[m], prj[m]
        _, xy = surface_points(res.kc, res.rvecs, res.tvecs, cam, np.full(len(cam), i), *dc,
                               res.board_surface)
        keep = outside_field(xy, (6, 9), 24.0, 0.25)
        xy, prj = xy[keep], prj[keep]
        _, inl = cv2.findHomography(xy, prj, cv2.RANSAC, 3.0)
        inl = inl.ravel() > 0
        h = res.board_surface.height(xy[inl])
        flat.append(np.column_stack([xy[inl], np.zeros(inl.sum())]).astype(np.float32))
        shaped.append(np.column_stack([xy[inl], h]).astype(np.float32))
        img.append(prj[inl].astype(np.float32))
    kp = res.kp
    K0 = np.array([[kp[0] * kp[3] / dp[0], 0, kp[1]], [0, kp[0] / dp[1], kp[2]], [0, 0, 1]])
    out = {"crossings": int(sum(len(o) for o in img))}
    # the image size only bounds the principal point (this projector's lies below its image)
    size = (800, 1400)
    for name, obj in (("corners' plane", flat), ("fitted white-part surface", shaped)):
        for terms, flags in (("4 terms", cv2.CALIB_FIX_K3), ("8 terms", cv2.CALIB_RATIONAL_MODEL)):
            rms = cv2.calibrateCamera(obj, img, size, K0.copy(), np.zeros(8),
                                      flags=flags | cv2.CALIB_USE_INTRINSIC_GUESS)[0]
            out[f"OpenCV, crossings on the {name}, {terms}: RMS 2-D / per coordinate (px)"] = \
                f"{rms:.3f} / {rms / np.sqrt(2):.3f}"
    return out


def line_scatter(res, cache: dict) -> dict:
    """RMS of all white-part centre-line residuals, of the line pieces' means and about them."""
    from nurbscan.calibrate import Target
    from nurbscan.calibrate._bundle import ProjObs, projector_residuals
    from nurbscan.calibrate.pipeline import consistent_labels, edge_observations

    keys = sorted(cache, key=lambda k: k[0])
    target = Target(6, 9, 24.0, margin=None)
    dc = tuple(res.figures["pixel_pitch_mm"]["camera"])
    dp = tuple(res.figures["pixel_pitch_mm"]["projector"])
    rs, keyv, along = [], [], []
    for i, k in enumerate(keys):
        _, _, det, area = cache[k]
        line = np.asarray(det.line)
        n = len(line)
        o = edge_observations(det, res.kc, res.rvecs[i], res.tvecs[i], target, i, dc,
                              10**9, white_area=area)
        pos = {(float(x), float(y)): j for j, (x, y) in enumerate(zip(det.x, det.y,
                                                                        strict=True))}
        idx = np.array([pos[(float(x), float(y))] for x, y in o.pixels], np.int64)
        good = consistent_labels(o, det, res.kc, res.rvecs, res.tvecs, dc)
        o = ProjObs(o.pixels[good], o.value[good], o.axis[good], o.view[good], o.sign[good])
        r = projector_residuals(res.kc, res.rvecs, res.tvecs, res.kp, res.rp, res.tp, o, dc,
                                dp, None, res.board_surface)
        rs.append(r)
        keyv.append(i * (n + 1) + line[idx[good]])
        along.append(np.where(o.axis == 0, o.pixels[:, 1], o.pixels[:, 0]))
    r, key, along = (np.concatenate(a) for a in (rs, keyv, along))
    _, inv, cnt = np.unique(key, return_inverse=True, return_counts=True)
    mean = (np.bincount(inv, r) / cnt)[inv]
    w = r - mean
    o = np.lexsort((along, key))
    out = {"centre-line points": int(len(r)), "RMS (projector px)": float(np.sqrt(np.mean(r**2))),
           "RMS of each line piece's mean (projector px)": float(np.sqrt(np.mean(mean**2))),
           "scatter about each line piece's mean, RMS (projector px)": float(
               np.sqrt(np.mean(w**2)))}
    for lag in (1, 4, 16):
        same = key[o][lag:] == key[o][:-lag]
        out[f"scatter's correlation along the line at {lag} camera px"] = float(
            np.corrcoef(w[o][lag:][same], w[o][:-lag][same])[0, 1])
    return out


def source_nodes(data: Path) -> dict:
    """OpenCV on the source's own node pairs, the nodes on the plane of its camera poses."""
    import cv2

    fs = cv2.FileStorage(str(data / "reference" / "calibration.yml"), cv2.FILE_STORAGE_READ)

    def seq(name):
        n = fs.getNode(name)
        return [n.at(i).mat() for i in range(n.size())]

    K, kc = fs.getNode("camK").mat(), fs.getNode("camKc").mat()
    obj, img = [], []
    for c, p, rv, tv in zip(seq("camImgPts"), seq("prjImgPts"), seq("camRvecs"),
                            seq("camTvecs"), strict=True):
        und = cv2.undistortPoints(c.reshape(-1, 1, 2).astype(np.float64), K, kc).reshape(-1, 2)
        R = cv2.Rodrigues(rv.reshape(3))[0]
        t = tv.reshape(3)
        d = np.column_stack([und, np.ones(len(und))])
        X = d * ((R[:, 2] @ t) / (d @ R[:, 2]))[:, None]
        xb = (X - t) @ R
        obj.append(np.column_stack([xb[:, :2], np.zeros(len(xb))]).astype(np.float32))
        img.append(p.astype(np.float32))
    rms = cv2.calibrateCamera(obj, img, (800, 600), None, None, flags=cv2.CALIB_FIX_K3)[0]
    return {"nodes": int(sum(len(o) for o in obj)),
            "OpenCV, the source's nodes on their poses' planes, 4 terms: RMS 2-D / per "
            "coordinate (px)": f"{rms:.3f} / {rms / np.sqrt(2):.3f}",
            "the source's published projector RMS, nodes free in 3-D (px, 2-D)": float(
                fs.getNode("prjReprojErr").real())}


def bench() -> dict:
    from nurbscan.calibrate import calibrate_scan

    conv = _load("real_procam")
    data = conv.data_dir()
    if data is None:
        return {"skipped": f"real procam set not found ({conv.REL_PATH} or ${conv.ENV})"}
    with tempfile.TemporaryDirectory(prefix="real_bound_") as tmp:
        scans = conv.lay_out(Path(tmp), data)
        cache: dict = {}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = calibrate_scan(scans["calib"] / "calibration", pose_cache=cache,
                                 max_points_per_view=300)
        out = {"calibration projector RMS (projector px)": res.figures["projector_rms_px"]}
        out |= opencv_on_crossings(res, cache)
        out |= line_scatter(res, cache)
    out |= source_nodes(data)
    return out


if __name__ == "__main__":
    for k, v in bench().items():
        print(f"{k}: {v:.4g}" if isinstance(v, float) else f"{k}: {v}")
    sys.exit(0)
