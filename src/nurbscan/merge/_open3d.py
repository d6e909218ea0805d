"""Open3D, imported once for every stage that uses it (registration, fusion, evaluation).

:func:`import_open3d` returns the ``open3d`` module with its log quiet (errors only), or
raises a one-line :class:`~nurbscan.errors.NurbscanError` saying why it cannot be imported
(e.g. ``libusb-1.0.so.0`` missing on a bare Debian).

Its plotting stack is not imported until used. ``import open3d`` imports
``open3d.visualization.draw_plotly``, and with it Dash, Plotly and IPython: 0.43 s of the
0.78 s the import takes (``python -X importtime``, Open3D 0.18/0.19), paid by every
``nurbscan reconstruct`` and by every Dask worker at its start, for functions nurbscan never
calls. Before Open3D is first imported, a stand-in module of that name is registered whose
``draw_plotly``, ``draw_plotly_server`` and ``get_plotly_fig`` import the real module when
called (as does any other attribute asked of it), so Open3D works as before for code that
plots.
"""

from __future__ import annotations

import importlib
import sys
import types

import numpy as np

from ..errors import NurbscanError

__all__ = ["import_open3d", "raycasting_scene"]

#: Open3D's plotting module, which imports Dash, Plotly and IPython, and the names
#: ``open3d.visualization`` imports from it.
PLOTTING = "open3d.visualization.draw_plotly"
PLOTTING_NAMES = ("get_plotly_fig", "draw_plotly", "draw_plotly_server")


def _real_plotting():
    """Open3D's real plotting module, imported in place of the stand-in."""
    if isinstance(sys.modules.get(PLOTTING), _Deferred):
        del sys.modules[PLOTTING]
    return importlib.import_module(PLOTTING)


class _Deferred(types.ModuleType):
    """Stand-in for :data:`PLOTTING`: every public attribute is the real module's, imported
    then (the import system's own questions, such as ``__path__``, are answered here)."""

    def __getattr__(self, name):
        if name.startswith("__"):
            raise AttributeError(name)
        return getattr(_real_plotting(), name)


def _deferred_call(name: str):
    def call(*args, **kwargs):
        return getattr(_real_plotting(), name)(*args, **kwargs)

    call.__name__ = call.__qualname__ = name
    call.__doc__ = f"Open3D's ``{name}``, its module imported at the first call."
    return call


def _defer_plotting() -> None:
    """Register the stand-in for :data:`PLOTTING` unless Open3D is imported already."""
    if "open3d" in sys.modules or PLOTTING in sys.modules:
        return
    stand_in = _Deferred(PLOTTING, "Open3D's plotting module, imported when first used.")
    for name in PLOTTING_NAMES:
        setattr(stand_in, name, _deferred_call(name))
    sys.modules[PLOTTING] = stand_in


def import_open3d(what: str = "Open3D"):
    """The ``open3d`` module (log level: errors), its plotting stack deferred.

    Parameters
    ----------
    what : str
        The step that needs it, for the error (``"fusion"``, ``"global registration"``).

    Raises
    ------
    NurbscanError
        When Open3D cannot be imported: ``"{what}: Open3D cannot be imported (...)"``.
    """
    _defer_plotting()
    try:
        import open3d as o3d
    except ImportError as exc:  # e.g. libusb-1.0.so.0 missing (Debian: libusb-1.0-0)
        raise NurbscanError(f"{what}: Open3D cannot be imported ({exc})") from None
    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    return o3d


def raycasting_scene(vertices, faces, what: str = "Open3D"):
    """An Open3D ``RaycastingScene`` (a BVH over the triangles; exact ray hits and
    point-to-triangle distances) of a triangle mesh: ``vertices`` (V, 3) mm, ``faces``
    (F, 3) vertex indices; ``what`` names the step in the import error
    (:func:`import_open3d`)."""
    o3d = import_open3d(what)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(np.asarray(vertices, np.float32)),
                        o3d.core.Tensor(np.asarray(faces, np.uint32)))
    return scene
