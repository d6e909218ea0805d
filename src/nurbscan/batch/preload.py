"""What a Dask worker does once at its start (``dask worker --preload nurbscan.batch.preload``).

1. **Memory reuse.** Dask's nanny starts each worker with ``MALLOC_TRIM_THRESHOLD_=65536``
   (``distributed.nanny.pre-spawn-environ``), which also turns off glibc's adaptive mmap
   threshold: every numpy temporary over 128 kB is then mapped and unmapped anew. A
   1024 x 768 view task took 94 000 page faults in a worker against 12 000 in ``nurbscan
   reconstruct``, and about 1.3 times its CPU time. Here glibc's thresholds are set back to
   its own adaptive maximum (``mallopt``: trim above 64 MiB, map above 32 MiB), on glibc only,
   as in every worker process nurbscan starts (:mod:`nurbscan._malloc`).
2. **Imports.** The tasks import the detector, the reconstruction, the fusion (Open3D) and
   the export (trimesh, rhino3dm) lazily; imported here, a worker's first task runs as fast as
   its later ones and the imports count in the cluster's start-up, not in a scan's tasks.
   Open3D alone (with the plotting stack it imports) took 0.93 s of the first finish task's
   5.9 s on a 1024 x 768 scan, the lazy imports 1.59 s in all. Open3D's plotting stack (Dash,
   Plotly, IPython) is left out (:mod:`nurbscan.merge._open3d`) and the registration's
   chi-square quantiles need no ``scipy.stats``: the preload's CPU time went from 2.09 to
   1.57 s (a shared machine; ``python -X importtime -c "import nurbscan.batch.preload"``).
3. **One OpenCV thread.** Dask's nanny gives each worker ``OMP_NUM_THREADS=1`` (one thread of
   BLAS and OpenMP per worker thread: the parallelism is across tasks), but OpenCV starts its
   own pool of one thread per core in every worker; two workers on two cores then run four
   filter threads. Here OpenCV is set to one thread (:data:`OPENCV_THREADS`).
"""

from __future__ import annotations

from .._malloc import reuse_freed_memory

#: OpenCV threads per worker (``cv2.setNumThreads``): one, as Dask's nanny does for OpenMP.
OPENCV_THREADS = 1


def one_thread_per_task() -> None:
    """Set OpenCV's thread pool to :data:`OPENCV_THREADS` (its filters give the same values)."""
    import cv2

    cv2.setNumThreads(OPENCV_THREADS)


reuse_freed_memory()
one_thread_per_task()

from ..detect import detect_grid  # noqa: E402, F401
from ..evaluate import evaluate_model  # noqa: E402, F401
from ..export import export_model  # noqa: E402, F401
from ..merge.fusion import fuse_model  # noqa: E402, F401
from ..merge.register import _o3d  # noqa: E402
from ..reconstruct.pipeline import assemble_scan, run_view  # noqa: E402, F401
from .tasks import finish_task  # noqa: E402, F401

_o3d()  # Open3D, imported where the registration and the fusion first need it
import scipy.ndimage  # noqa: E402, F401
import trimesh  # noqa: E402, F401
