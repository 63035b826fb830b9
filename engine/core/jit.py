"""The numba decorators every kernel is compiled with, and the thread count.

``kernel`` compiles a function for one world (or a helper of one);
``parallel_kernel`` a loop over worlds with ``prange``. Both cache their
machine code next to the source (``cache=True``), keep IEEE semantics
(``fastmath=False``: no reassociation, no contraction into fused
multiply-adds, so a result never depends on how a loop was vectorised) and
return inf/NaN on a division by zero instead of raising
(``error_model="numpy"``); denominators are guarded where it matters.
"""

from __future__ import annotations

import numbers
import os

import numba

# engine.ParallelStepper forks worker processes that step with these kernels.
# GNU OpenMP (numba's "omp" layer on Linux) terminates a forked child that
# enters a parallel region once its parent has used one; "forksafe" takes TBB
# where it is installed and numba's own workqueue otherwise, both safe across
# fork. Set before any parallel kernel runs, which is when numba loads the
# layer; an explicit NUMBA_THREADING_LAYER is kept.
if "NUMBA_THREADING_LAYER" not in os.environ:
    numba.config.THREADING_LAYER = "forksafe"

kernel = numba.njit(cache=True, fastmath=False, error_model="numpy", nogil=True)
parallel_kernel = numba.njit(cache=True, fastmath=False, error_model="numpy", nogil=True, parallel=True)
prange = numba.prange

#: Below this many worlds a batch is stepped on the calling thread: waking the
#: worker threads costs more than a small batch's step.
SERIAL_BELOW = 8
#: The same for kernels looping over rows (contact rows of all worlds): a
#: row's work is a few hundred operations, so many rows pay for the wake-up.
SERIAL_ROWS_BELOW = 1024


def set_threads(n: int | None = None) -> int:
    """Use ``n`` threads for batched steps (None: all cores numba sees).

    The thread count changes no bit of any trajectory: each world is stepped
    by one thread from start to end. Returns the count now in use.
    """
    if n is None:
        n = numba.config.NUMBA_NUM_THREADS
    if isinstance(n, bool) or not isinstance(n, numbers.Integral) or not 1 <= n <= numba.config.NUMBA_NUM_THREADS:
        raise ValueError(f"threads must be an integer in 1..{numba.config.NUMBA_NUM_THREADS} "
                         f"(NUMBA_NUM_THREADS), got {n!r}")
    numba.set_num_threads(int(n))
    return int(n)


def get_threads() -> int:
    """The number of threads batched steps use."""
    return numba.get_num_threads()


def jit_disabled() -> bool:
    """Whether ``NUMBA_DISABLE_JIT`` is set (kernels run as plain Python)."""
    return bool(int(os.environ.get("NUMBA_DISABLE_JIT", "0") or 0))
