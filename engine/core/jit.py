"""The numba decorators every kernel is compiled with, and the thread count.

``kernel`` compiles a function for one world (or a helper of one) that
allocates nothing, without numba's reference counting;
``allocating_kernel`` one that allocates or returns arrays;
``parallel_kernel`` a loop over worlds with ``prange``. All cache their
machine code next to the source (``cache=True``), keep IEEE semantics
(``fastmath=False``: no reassociation, no contraction into fused
multiply-adds, so a result never depends on how a loop was vectorised) and
return inf/NaN on a division by zero instead of raising
(``error_model="numpy"``); denominators are guarded where it matters.

A batched step (W >= ``SERIAL_BELOW`` worlds) runs its ``prange`` loops on
numba's worker threads and its substeps (``over_worlds``) as ranges of
worlds on a pool of Python threads calling a kernel that releases the GIL;
either way each world is on one thread from start to end, so the thread
count changes no bit. ``set_threads`` chooses it (default: all cores,
``NUMBA_NUM_THREADS``). The threading layer is GNU OpenMP where it loads
(its launch is cheap; see below): after a batched step in a process, its
``fork()``ed children must not run batched steps (use the ``spawn`` or
``forkserver`` start methods).
"""

from __future__ import annotations

import numbers
import os
import threading
from concurrent.futures import ThreadPoolExecutor

import numba

# The threading layer: GNU OpenMP ("omp") first, for its cheap launch (a
# step makes many parallel-kernel calls; the figures are in docs/decisions.md).
# numba tries the layers in this order and takes the first that loads, so a
# machine without libgomp falls back to TBB, then to workqueue, instead of
# failing. Set before any parallel kernel runs, which is when numba loads the
# layer; an explicit NUMBA_THREADING_LAYER or NUMBA_THREADING_LAYER_PRIORITY is
# kept. OpenMP's idle workers spin (take set_threads(1) on a machine another
# process keeps busy); OMP_WAIT_POLICY=PASSIVE makes them sleep, left to the
# user because libgomp is shared with torch in the same process (README).
#
# The fork caveat: GNU OpenMP terminates a fork()ed child that enters a
# parallel region once its parent has used one. After a batched step
# (W >= SERIAL_BELOW) in a process, children that run batched steps must be
# started with the "spawn" or "forkserver" multiprocessing start methods.
if "NUMBA_THREADING_LAYER" not in os.environ and "NUMBA_THREADING_LAYER_PRIORITY" not in os.environ:
    numba.config.THREADING_LAYER_PRIORITY = ["omp", "tbb", "workqueue"]
    numba.config.THREADING_LAYER = "default"

#: A kernel allocates nothing (its scratch comes from its caller) and so is
#: compiled without numba's reference counting (``_nrt=False``): passing an
#: array or taking a view of one costs no atomic count. It may return
#: scalars and tuples of them, never an array.
kernel = numba.njit(cache=True, fastmath=False, error_model="numpy", nogil=True, _nrt=False)
#: A kernel that allocates arrays or returns them (or calls one that does):
#: numba's reference counting frees them.
allocating_kernel = numba.njit(cache=True, fastmath=False, error_model="numpy", nogil=True)
#: ``kernel`` for a helper called only from other kernels, inlined into its
#: callers by numba (``inline="always"``): no wrappers for calls from
#: Python (for a helper taking many tuples of arrays they cost seconds of
#: compile time each) and no call. Inside an ``allocating_kernel`` a call
#: still counts a reference to each array it is passed, and an inlined
#: helper each array of a tuple bound to its argument (two atomic
#: operations each); inside a ``kernel`` nothing is counted.
inlined_kernel = numba.njit(cache=True, fastmath=False, error_model="numpy", nogil=True, no_cpython_wrapper=True,
                            no_cfunc_wrapper=True, inline="always")
parallel_kernel = numba.njit(cache=True, fastmath=False, error_model="numpy", nogil=True, parallel=True)
prange = numba.prange

#: Below this many worlds a batch is stepped on the calling thread: waking the
#: worker threads costs more than a small batch's step.
SERIAL_BELOW = 8
#: The same for kernels looping over rows (contact rows of all worlds): a
#: row's work is a few hundred operations, so many rows pay for the wake-up.
SERIAL_ROWS_BELOW = 1024


def max_threads() -> int:
    """The most threads batched steps can use: numba's ``NUMBA_NUM_THREADS``
    (all cores unless set in the environment before numba loads)."""
    return int(numba.config.NUMBA_NUM_THREADS)


def set_threads(n: int | None = None) -> int:
    """Use ``n`` threads for batched steps (None: all cores numba sees).

    The thread count changes no bit of any trajectory: each world is stepped
    by one thread from start to end. The count is numba's, which keeps one
    per calling thread: it applies to the steps this thread makes (another
    Python thread starts with all cores). Returns the count now in use.
    """
    if n is None:
        n = max_threads()
    if isinstance(n, bool) or not isinstance(n, numbers.Integral) or not 1 <= n <= max_threads():
        raise ValueError(f"threads must be an integer in 1..{max_threads()} "
                         f"(NUMBA_NUM_THREADS), got {n!r}")
    numba.set_num_threads(int(n))
    return int(n)


_pool: ThreadPoolExecutor | None = None
_pool_pid = 0  # the process that made _pool: a fork()ed child has none of its threads
_pool_lock = threading.Lock()


def over_worlds(kernel_of_range, args, num_worlds: int) -> None:
    """Run ``kernel_of_range(*args, first, stop)``, a kernel stepping the
    worlds first..stop-1, over all ``num_worlds`` worlds: on the calling
    thread below ``SERIAL_BELOW`` worlds or with one thread, else in
    ``get_threads()`` contiguous ranges on as many threads. The kernel must
    be compiled with ``nogil=True`` (``kernel`` is), so the ranges run at
    once; each world is stepped by one thread, so the count changes no bit.

    For a kernel whose arguments are many tuples of arrays, where a
    ``prange`` loop would cost minutes of compile time (numba's parallel
    lowering grows steeply with a tuple's fields)."""
    global _pool, _pool_pid
    threads = min(get_threads(), num_worlds)
    if num_worlds < SERIAL_BELOW or threads <= 1:
        kernel_of_range(*args, 0, num_worlds)
        return
    with _pool_lock:
        if _pool is None or _pool_pid != os.getpid():
            # One worker per thread numba may use (set_threads never asks for more).
            _pool = ThreadPoolExecutor(max_workers=max_threads(), thread_name_prefix="ragdoll-worlds")
            _pool_pid = os.getpid()
        pool = _pool
    bounds = [num_worlds * k // threads for k in range(threads + 1)]
    # The calling thread takes the first range itself.
    futures = [pool.submit(kernel_of_range, *args, bounds[k], bounds[k + 1]) for k in range(1, threads)]
    kernel_of_range(*args, bounds[0], bounds[1])
    for f in futures:
        f.result()


def get_threads() -> int:
    """The number of threads batched steps use."""
    return numba.get_num_threads()


def jit_disabled() -> bool:
    """Whether ``NUMBA_DISABLE_JIT`` is set (kernels run as plain Python)."""
    return bool(int(os.environ.get("NUMBA_DISABLE_JIT", "0") or 0))
