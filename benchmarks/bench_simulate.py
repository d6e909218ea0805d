"""Benchmark of the synthetic scanner: one 7.1 MP teapot view with its white-light image.

Target (issue 3): at most 15 s on the 2-core machine and at most 4 GB of memory. The scene's
one-off set-up (mesh, bounds, ray engine) is timed separately from the view.
"""

from __future__ import annotations

import os
import resource
import time


def bench() -> dict:
    from nurbscan.simulate.render import RenderSettings, render_view
    from nurbscan.simulate.rig import default_rig
    from nurbscan.simulate.scan import default_pattern
    from nurbscan.simulate.scenes import make_scene

    rig = default_rig()
    pattern = default_pattern(rig.projector)
    t0 = time.perf_counter()
    scene = make_scene("teapot")
    scene.mesh()
    _ = scene.bounds
    scene.intersect([[0.0, 0.0, 500.0]], [[0.0, 0.0, -1.0]])
    setup = time.perf_counter() - t0
    t0 = time.perf_counter()
    c0 = resource.getrusage(resource.RUSAGE_SELF)
    view = render_view(scene, rig, pattern, 0.5, RenderSettings(), seed=0)
    total = time.perf_counter() - t0
    c1 = resource.getrusage(resource.RUSAGE_SELF)
    cpu = (c1.ru_utime - c0.ru_utime) + (c1.ru_stime - c0.ru_stime)
    load = os.getloadavg()[0]
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    st = view.stats
    return {
        "camera (px)": f"{rig.camera.width} x {rig.camera.height}",
        "threads": os.cpu_count(),
        "scene set-up, once per scene (s)": setup,
        "one view: grid + white image + truth (s)": total,
        "one view: CPU time, all threads (s)": cpu,
        "machine load average during the run (1 min)": load,
        "target (s)": 15.0,
        "phases (s)": {
            "pixel-centre rays (hit, shadow, shading)": st.get("centre_rays_s", float("nan")),
            "interpolated pixels (pattern area integral)": st.get("smooth_pixels_s",
                                                                   float("nan")),
            "traced pixels (4 x 4 rays)": st.get("exact_pixels_s", float("nan")),
            "sensor (blur, noise, gamma, quantisation)": st.get("sensor_s", float("nan")),
        },
        "lit pixels interpolated": st.get("smooth_lit_pixels", 0),
        "pixels traced with 16 rays": st.get("exact_pixels", 0),
        "peak memory after the view (MB)": peak,
    }


if __name__ == "__main__":
    import json

    print(json.dumps(bench(), indent=1, default=float))
