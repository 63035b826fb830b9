"""The compiled kernels of the step (numba).

Every kernel here is written for one world: scalar loops over its bodies,
rows and contacts, as Box2D's solver is written. A batch of W worlds runs
the same kernel once per world in a ``prange`` loop (:mod:`engine.core.batch`),
so W worlds stepped together give bit for bit what each gives alone, at any
thread count. Conventions:

* vectors and quaternions inside a kernel are tuples of floats
  (:mod:`engine.core.vec`), which stay in registers; arrays are read and
  written only at the edges of a kernel;
* every kernel is compiled with :data:`engine.core.jit.kernel`
  (``cache=True``, ``fastmath=False``, ``error_model="numpy"``), so there is
  no reassociation, no fused multiply-add and no exception on 0/0;
* ``NUMBA_DISABLE_JIT=1`` runs the same code as plain Python, for debugging.

Builder, validation and queries stay in Python/numpy outside this package.
"""
