"""nurbscan._jit: compiled loops loaded only when first run."""

import subprocess
import sys

import numpy as np


def test_importing_the_stages_does_not_start_llvm():
    """A process that imports the stages but runs no compiled loop has no numba (nor LLVM)
    loaded; the first compiled loop loads it."""
    code = ("import sys, numpy as np\n"
            "import nurbscan.detect, nurbscan.reconstruct, nurbscan.calibrate, nurbscan.cli\n"
            "print('numba' in sys.modules, 'llvmlite' in sys.modules)\n"
            "from nurbscan.detect.neighbours import nearest_within\n"
            "nearest_within(np.zeros((3, 2)), np.zeros((1, 2)), 2, 1.0)\n"
            "print('numba' in sys.modules)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.split()
    assert out == ["False", "False", "True"]


def test_marked_functions_compile_together_and_call_one_another():
    """The first call compiles every marked function of the module (numba dispatchers in
    their place), and a compiled function calls another: the results are the plain Python
    functions' own."""
    import nurbscan.detect.lines as lines

    rng = np.random.default_rng(0)
    a = rng.normal(size=(13, 40))
    got = lines._row_sums(a)  # calls _pairwise_sum from Python
    assert got.tobytes() == np.ascontiguousarray(a.T).sum(1).tobytes()
    assert type(lines._pairwise_sum).__name__ == "CPUDispatcher"
    assert type(lines._window_fits).__name__ == "CPUDispatcher"  # compiled with its module
    # a compiled function calling another (_window_fits -> _pairwise_sum), against numpy
    along, across = np.arange(20.0), rng.normal(size=20)
    c0, c1, sw, _ = lines._window_fit(along, across, np.zeros(20, np.int64), np.arange(-2, 3))
    assert sw[0] == 3 and sw[10] == 5
    k = np.polyfit(np.arange(-2, 3.0), across[8:13], 1)
    np.testing.assert_allclose([c1[10], c0[10]], k, rtol=1e-10)
