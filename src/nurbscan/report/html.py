"""The scan report: one HTML file with everything inlined, no network.

Sections: an interactive 3-D view of the model (three.js, vendored in ``static/`` with its
licence, inlined as ``data:`` modules through an import map; the meshes are GLB files embedded
as base64 and read by ``static/viewer.js``) with a colour view (white-light vertex colours) and
an error heat map (per-vertex distance to the true surface, when the scan's ``truth/`` is
found); the accuracy table beside the paper's Table I (``evaluation.json``); per-view figures;
the detected-line overlays (PNG data URIs, downscaled); the model's picture (``model.png``).
"""

from __future__ import annotations

import base64
import html
import json
import os
from importlib import resources
from pathlib import Path

import cv2
import numpy as np

from ..errors import NurbscanError
from ..io.atomic import read_json, write_text
from ..io.images import read_image

__all__ = ["build_report", "detect_overlays", "error_colours", "find_overlays", "report_html",
           "vertex_errors", "write_report"]

ROWS = ("horizontal_lines", "vertical_lines", "horizontal_skin", "vertical_skin", "gordon")


def _static(name: str) -> bytes:
    return resources.files("nurbscan.report").joinpath("static", name).read_bytes()


def _b64(data: bytes) -> str:
    return base64.b64encode(data).decode("ascii")


def _read_bgr(path: str | os.PathLike, what: str) -> np.ndarray:
    """An image file as BGR in its own sample type (:func:`nurbscan.io.read_image`: a size
    over its limit in the header, or a file that does not decode, is a one-line error naming
    ``path`` and ``what`` it is)."""
    try:
        return np.ascontiguousarray(read_image(path, as_float=False)[..., ::-1])
    except NurbscanError as exc:
        raise NurbscanError(f"{exc} (the {what})") from None


def _png_uri(img_bgr: np.ndarray, max_width: int = 640) -> str:
    """A PNG data URI of a BGR image, downscaled (area averaging) to at most ``max_width``."""
    h, w = img_bgr.shape[:2]
    if w > max_width:
        img_bgr = cv2.resize(img_bgr, (max_width, max(1, round(h * max_width / w))),
                             interpolation=cv2.INTER_AREA)
    if img_bgr.dtype != np.uint8:
        img_bgr = np.clip(img_bgr / (65535.0 if img_bgr.dtype == np.uint16 else 1.0) * 255,
                          0, 255).astype(np.uint8)
    ok, png = cv2.imencode(".png", img_bgr)
    if not ok:  # pragma: no cover
        raise NurbscanError("report: PNG encoding failed")
    return "data:image/png;base64," + _b64(png.tobytes())


def find_overlays(*folders) -> list[Path]:
    """Overlay pictures (``*overlay*.png``) in the given folders and their ``overlays/``."""
    out: list[Path] = []
    for f in folders:
        if f is None or not Path(f).is_dir():
            continue
        for pat in ("*overlay*.png", "overlays/*.png", "views/*overlay*.png"):
            out += sorted(Path(f).glob(pat))
    seen, uniq = set(), []
    for p in out:
        if p.resolve() not in seen:
            seen.add(p.resolve())
            uniq.append(p)
    return uniq


def vertex_errors(vertices: np.ndarray, truth_dir: str | os.PathLike) -> np.ndarray:
    """Distance (mm) of each vertex (N, 3), object frame, to the true surface of a scan."""
    from ..simulate.scenes import scene_from_dict

    truth = Path(truth_dir)
    scene = scene_from_dict(read_json(truth / "scene.json"))
    return np.asarray(scene.distance(np.asarray(vertices, float)), float)


def error_colours(err: np.ndarray, vmax: float) -> np.ndarray:
    """RGBA uint8 (N, 4) of errors on a blue-green-yellow-red ramp over [0, vmax] mm."""
    stops = np.array([[49, 54, 149], [69, 117, 180], [116, 196, 118], [254, 224, 76],
                      [215, 48, 39]], float)
    t = np.clip(np.asarray(err, float) / max(vmax, 1e-12), 0, 1) * (len(stops) - 1)
    i = np.minimum(t.astype(int), len(stops) - 2)
    f = (t - i)[:, None]
    rgb = stops[i] * (1 - f) + stops[i + 1] * f
    out = np.full((len(rgb), 4), 255, np.uint8)
    out[:, :3] = np.round(rgb).astype(np.uint8)
    return out


def _fmt(x, nd: int = 4) -> str:
    if x is None:
        return "-"
    if isinstance(x, int | np.integer):
        return str(int(x))
    x = float(x)
    return f"{x:.{nd}f}" if abs(x) >= 10 ** -nd or x == 0 else f"{x:.2e}"


def _table_html(ev: dict) -> str:
    head = ("<tr><th rowspan=2>entity</th><th rowspan=2>n</th><th colspan=4>this scan (mm)</th>"
            "<th rowspan=2>max sample</th><th colspan=4>paper, Table I (mm)</th></tr>"
            "<tr><th>mean</th><th>std</th><th>min</th><th>max</th>"
            "<th>mean</th><th>std</th><th>min</th><th>max</th></tr>")
    body = []
    for key in ROWS:
        r = ev.get("rows", {}).get(key)
        if r is None:
            continue
        p = r.get("paper") or {}
        cells = [html.escape(str(r.get("label", key))), _fmt(r.get("n"))]
        cells += [_fmt(r.get(k)) for k in ("mean_mm", "std_mm", "min_mm", "max_mm",
                                           "max_sample_mm")]
        cells += [_fmt(p.get(k)) for k in ("mean_mm", "std_mm", "min_mm", "max_mm")]
        body.append("<tr>" + "".join(f"<td>{c}</td>" for c in cells) + "</tr>")
    extra = ""
    if "coverage" in ev:
        extra = (f"<p>Coverage of the camera-visible true surface by Gordon patches (within "
                 f"{_fmt(ev.get('coverage_tolerance_mm'), 2)} mm): "
                 f"<b>{100 * float(ev['coverage']):.1f}%</b>.</p>")
    return f"<table class=num>{head}{''.join(body)}</table>{extra}"


def _views_html(model, ev: dict | None) -> str:
    evv = {int(v["index"]): v for v in (ev or {}).get("views", [])}
    rows = []
    for v in model.views:
        k = int(v.get("index", 0))
        e = evv.get(k, {})
        cells = [k, _fmt(np.degrees(float(v.get("table_angle", 0.0))), 1),
                 v.get("network_lines", ["-", "-"]), v.get("patches", "-"),
                 _fmt(v.get("rms2d_px")), _fmt(e.get("gordon")),
                 "-" if e.get("coverage") is None else f"{100 * e['coverage']:.1f}%",
                 _fmt(v.get("image_to_gordon_s"), 2)]
        rows.append("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in cells) + "</tr>")
    head = ("<tr><th>view</th><th>table angle (deg)</th><th>network lines [v, h]</th>"
            "<th>patches</th><th>2-D fit RMS (px)</th><th>Gordon mean error (mm)</th>"
            "<th>coverage</th><th>image to Gordon (s)</th></tr>")
    return f"<table class=num>{head}{''.join(rows)}</table>"


CSS = """
body{font-family:system-ui,sans-serif;margin:0;color:#1d2229;background:#f4f5f7}
header{padding:8px 16px;background:#1d2229;color:#eee}header h1{font-size:18px;margin:0}
main{padding:0 16px 24px}section{margin:16px 0}
#viewer{width:100%;height:440px;background:#1d2229;position:relative}
#viewer canvas{display:block}
.bar{display:flex;gap:8px;align-items:center;margin:6px 0;font-size:13px}
button{border:1px solid #999;background:#fff;padding:3px 10px;cursor:pointer}
button.on{background:#1d2229;color:#fff}
#legend{font-size:12px}#legend .ramp{display:inline-block;width:160px;height:10px;
background:linear-gradient(90deg,#313695,#4575b4,#74c476,#fee04c,#d73027);vertical-align:middle}
table.num{border-collapse:collapse;font-size:13px}table.num td,table.num th{border:1px solid
#ccc;padding:2px 8px;text-align:right}table.num th{background:#e6e8eb}
.gallery{display:flex;flex-wrap:wrap;gap:8px}.gallery figure{margin:0}
.gallery img{max-width:380px;width:100%;border:1px solid #ccc}figcaption{font-size:12px}
"""


def report_html(title: str, meshes: dict[str, bytes], evaluation: dict | None, model,
                overlays: list[tuple[str, str]], picture_uri: str | None,
                notes: list[str], error_range_mm: float | None) -> str:
    """Assemble the report page (a str). ``meshes``: name -> GLB bytes (first shown)."""
    three = _b64(_static("three.module.min.js"))
    orbit = _static("OrbitControls.js").decode("utf-8")
    orbit_uri = "data:text/javascript;base64," + _b64(orbit.encode())
    importmap = json.dumps({"imports": {
        "three": "data:text/javascript;base64," + three,
        "three/addons/controls/OrbitControls.js": orbit_uri}})
    viewer = _static("viewer.js").decode("utf-8")
    glbs = "".join(f'<script type="application/octet-stream" id="glb-{k}">{_b64(v)}</script>'
                   for k, v in meshes.items())
    buttons = "".join(f'<button data-show="{k}" class="{"on" if i == 0 else ""}">{k}</button>'
                      for i, k in enumerate(meshes))
    legend = ""
    if error_range_mm is not None:
        legend = (f'<span id=legend style="display:none">0 mm <span class=ramp></span> '
                  f"&ge; {_fmt(error_range_mm, 3)} mm (distance to the true surface)</span>")
    parts = [f"<!doctype html><html lang=en><head><meta charset=utf-8><title>"
             f"{html.escape(title)}</title><style>{CSS}</style>"
             f'<script type="importmap">{importmap}</script></head><body>',
             f"<header><h1>{html.escape(title)}</h1></header><main>",
             f"<section><div id=viewer></div><div class=bar>{buttons}{legend}"
             f"<span id=viewer-status>loading 3-D view</span></div></section>"]
    if notes:
        parts.append("<section><ul>" + "".join(f"<li>{html.escape(n)}</li>" for n in notes)
                     + "</ul></section>")
    if evaluation is not None:
        parts.append("<section><h2>Accuracy (Table I)</h2>" + _table_html(evaluation)
                     + "</section>")
    if model.views:
        parts.append("<section><h2>Views</h2>" + _views_html(model, evaluation) + "</section>")
    if overlays:
        figs = "".join(f"<figure><img src='{u}' alt='{html.escape(n)}'><figcaption>"
                       f"{html.escape(n)}</figcaption></figure>" for n, u in overlays)
        parts.append(f"<section><h2>Detected lines</h2><div class=gallery>{figs}</div></section>")
    if picture_uri:
        parts.append(f"<section><h2>Model picture</h2><div class=gallery><figure><img "
                     f"src='{picture_uri}' alt='model'><figcaption>front, side, top "
                     f"(orthographic)</figcaption></figure></div></section>")
    parts.append(f"</main>{glbs}<script type=module>{viewer}</script></body></html>")
    return "".join(parts)


def build_report(model_dir: str | os.PathLike, overlays=None, evaluation=None,
                 per_span: int | None = None, heat_map: bool = True,
                 detect: bool = True, progress=None) -> str:
    """The report page of a model folder.

    Parameters
    ----------
    model_dir : path-like
        Model folder (``model.json``; optional ``evaluation.json``, ``model.png``).
    overlays : list of path-like, optional
        Overlay PNGs; by default :func:`find_overlays` of the model and scan folders.
    evaluation : path-like, optional
        ``evaluation.json`` (default ``model_dir/evaluation.json`` if present).
    per_span : int, optional
        Tessellation grid intervals per knot span of the embedded meshes (default: as many as
        keep the mesh within 60000 vertices, at most 8).
    heat_map : bool
        Compute per-vertex errors against the scan's truth when it is found.
    detect : bool
        When no overlay picture is given or found, detect the lines of the scan's first views
        now (:func:`detect_overlays`) if the scan folder is found.
    """
    from ..export import _resolve, build_mesh, find_rig, find_white_images, fused_mesh, load_model
    from ..export.mesh import mesh_bytes

    say = progress or (lambda _msg: None)
    folder = Path(model_dir)
    say(f"load {folder}")
    model = load_model(folder)
    notes = []
    rig = find_rig(model)
    if getattr(model, "fused", None) is not None:  # the one model of the object
        say(f"the fused mesh ({len(model.fused.faces)} triangles)")
        mesh = fused_mesh(model)
        notes.append(f"Mesh: the fused mesh of the views, {len(mesh.vertices)} vertices, "
                     f"{len(mesh.faces)} triangles.")
    else:
        say("the per-view Gordon patches, tessellated and coloured")
        images = find_white_images(model) if rig is not None else {}
        mesh = build_mesh(model, rig, images, per_span=per_span)
        notes.append(f"Mesh: {mesh.info['patches']} patches, {mesh.info['vertices']} vertices, "
                     f"{mesh.info['faces']} triangles, watertight: {mesh.info['watertight']}; "
                     f"colour: {mesh.info['colour']}.")
    meshes = {"colour": mesh_bytes(mesh, "glb")}
    scan = _resolve(model.meta.get("source"), model)
    vmax = None
    if heat_map and scan is not None and (scan / "truth" / "scene.json").is_file():
        say("error heat map against the truth")
        err = vertex_errors(mesh.vertices, scan / "truth")
        vmax = float(np.percentile(err, 99)) or 1e-3
        heat = type(mesh)(mesh.vertices, mesh.faces, error_colours(err, vmax),
                          mesh.vertex_view, dict(mesh.info))
        meshes["error"] = mesh_bytes(heat, "glb")
        notes.append(f"Error heat map: vertex distance to the true surface, mean "
                     f"{err.mean():.4f} mm, 99th percentile {vmax:.4f} mm, max {err.max():.4f} mm.")
    else:
        notes.append("Error heat map: no ground truth found (a simulated scan's truth/); "
                     "see the accuracy table.")
    ev = None
    ev_path = Path(evaluation) if evaluation is not None else folder / "evaluation.json"
    if evaluation is not None or ev_path.is_file():  # one asked for must be read
        ev = read_json(ev_path)
        if (not isinstance(ev, dict) or ev.get("type") != "nurbscan.evaluation"
                or not isinstance(ev.get("rows", {}), dict)
                or not isinstance(ev.get("views", []), list)
                or not isinstance(ev.get("fused", {}), dict | type(None))):
            raise NurbscanError(f"{ev_path}: not a nurbscan evaluation (nurbscan evaluate's "
                                "evaluation.json)")
    if overlays is None:
        overlays = find_overlays(folder, scan)
    ov = []
    for p in overlays:  # read_image checks the header's size before decoding
        ov.append((Path(p).name, _png_uri(_read_bgr(p, "overlay image"))))
    if not ov and detect and scan is not None and (scan / "scan.json").is_file():
        say("detect the lines of the first views for the overlay pictures")
        ov = detect_overlays(scan, rig=rig)
    pic = folder / "model.png"
    pic_uri = None
    if pic.is_file():
        try:
            pic_uri = _png_uri(_read_bgr(pic, "picture"), 960)
        except NurbscanError:  # the picture is optional: the report is whole without it
            pic_uri = None
    title = f"nurbscan report: {folder.resolve().name}"
    return report_html(title, meshes, ev, model, ov, pic_uri, notes, vmax)


def write_report(model_dir: str | os.PathLike, output: str | os.PathLike, **kw) -> Path:
    """Write :func:`build_report` to ``output`` atomically (UTF-8) and return the path."""
    return write_text(output, build_report(model_dir, **kw))


def detect_overlays(scan_dir: str | os.PathLike, max_views: int = 4,
                    max_width: int = 640, rig=None) -> list[tuple[str, str]]:
    """Detected-line overlays of a scan's views, computed now: ``[(name, PNG data URI)]``.

    Runs :func:`nurbscan.detect.detect_grid` on the grid image of each of the first
    ``max_views`` views (normalised by its white image; with the calibrated ``rig``, when
    its camera has the image's size, also decoding with its epipolar constraint as
    ``nurbscan reconstruct`` does) and draws :func:`nurbscan.detect.draw_overlay`; views
    whose images are missing are left out.
    """
    import functools
    import warnings

    from ..detect import detect_grid, draw_overlay
    from ..io import read_image
    from ..pattern import load_pattern
    from ..reconstruct.light import other_coordinate

    scan = Path(scan_dir)
    doc = read_json(scan / "scan.json")
    side = (doc.get("pattern") or {}).get("sidecar", "pattern.json")
    if not (scan / side).is_file():
        return []
    pattern = load_pattern(scan / side)
    out = []
    for v in doc.get("views", [])[:max_views]:
        grid, white = scan / str(v.get("grid", "")), scan / str(v.get("white", ""))
        if not grid.is_file():
            continue
        image = read_image(grid, as_float=False)
        wimg = read_image(white, as_float=False) if white.is_file() else None
        epipolar = None
        if rig is not None and (rig.camera.width, rig.camera.height) == image.shape[1::-1]:
            epipolar = functools.partial(other_coordinate, rig)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = detect_grid(image, pattern, wimg, epipolar=epipolar)
        rgb = draw_overlay(image, res, pattern)
        out.append((f"view {v.get('index')}: {res.nlines} lines ({grid.name})",
                    _png_uri(cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), max_width)))
    return out
