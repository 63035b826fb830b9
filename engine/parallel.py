"""Stepping the worlds of one state in several processes.

A step has no coupling between worlds, and each world's arithmetic is its
own (the step never lets a result depend on how many worlds share a call), so
W worlds can be cut into contiguous slices and each slice stepped in its own
process: the result is bit for bit the single-process step. The state's arrays
move into one anonymous shared mapping that the workers inherit (forked, with
the model as it was when the stepper was made); a step sends each worker its
slice of the control through a pipe and waits for all of them.

What two processes gain over one depends on W and on the machine: see the
``batched-2proc`` rows against the ``batched`` rows of the README's
Throughput table (``python -m benchmarks.throughput --processes 2``). On the
2-core machine of that table the gain grows with W, to 1.8-2x at W = 1024
(on the ground and in the air); at W = 16 it is small (about 1.1x), the
messages costing about what the second core gains.
"""

from __future__ import annotations

import mmap
import multiprocessing as mp
import signal

import numpy as np

from .control import Control
from .errors import SimulationError
from .state import State
from .step import _check_control, _check_state, _nonfinite_error, shift_worlds, step

_ALIGN = 64  # bytes: each array starts on a cache line


class ParallelStepper:
    """Step ``state`` (W worlds of ``model``) in ``processes`` worker processes.

    ``state``'s arrays are replaced by arrays in shared memory holding the same
    values (take references to them after this, not before; they stay valid
    after ``close``); read and write the state between steps as usual
    (``assign``, ``apply_impulse``, ...), the workers see it. The workers keep
    the model as it was at construction and step under the caller's numpy
    error state. Needs the ``fork`` start method (Linux). Use as a context
    manager or call ``close``; a worker that dies or fails closes the stepper
    and raises ``RuntimeError``.

        with ParallelStepper(model, state, processes=2) as stepper:
            for _ in range(steps):
                stepper.step(control)       # as engine.step(model, state, control)
    """

    def __init__(self, model, state: State, processes: int = 2):
        if not isinstance(processes, (int, np.integer)) or isinstance(processes, bool) or processes < 1:
            raise ValueError(f"processes must be an integer >= 1, got {processes!r}")
        _check_state(model, state)
        if "fork" not in mp.get_all_start_methods():
            raise RuntimeError("ParallelStepper needs the 'fork' start method, which this platform lacks; "
                               "use engine.step")
        self.model, self.state = model, state
        W = state.num_worlds
        self.bounds = np.linspace(0, W, min(int(processes), W) + 1).astype(int)
        _share(state)
        ctx = mp.get_context("fork")
        self._conns, self._procs = [], []
        # SIGINT blocked while forking: a worker ignores it from its first
        # instruction on (_worker), and a Ctrl-C meanwhile reaches the parent
        # once unblocked.
        mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
        try:
            try:
                for lo, hi in zip(self.bounds[:-1], self.bounds[1:]):
                    parent, child = ctx.Pipe()
                    p = ctx.Process(target=_worker, args=(child, model, state, int(lo), int(hi)), daemon=True)
                    p.start()
                    child.close()
                    self._conns.append(parent)
                    self._procs.append(p)
            finally:
                signal.pthread_sigmask(signal.SIG_SETMASK, mask)
        except BaseException:
            self.close()
            raise

    @property
    def processes(self) -> int:
        return len(self._procs)

    def _worlds(self, k):
        return f"worker {k} (worlds {self.bounds[k]}-{self.bounds[k + 1] - 1})"

    def step(self, control: Control | None = None) -> State:
        """``engine.step(model, state, control)`` with the worlds split over
        the workers: the control is checked first (ValueError before anything
        moves), events carry the state's world indices, and a world that turns
        non-finite raises the same ``SimulationError`` as ``engine.step``."""
        if not self._procs:
            raise RuntimeError("this ParallelStepper is closed")
        _check_state(self.model, self.state)
        control = _check_control(self.model, self.state, control)
        dead = [self._worlds(k) + " died" for k, p in enumerate(self._procs) if not p.is_alive()]
        if dead:
            self.close()
            raise RuntimeError("parallel step failed: " + "; ".join(dead))
        events, nonfinite, failures = [], False, []
        err = np.geterr()
        try:
            for k, (conn, lo, hi) in enumerate(zip(self._conns, self.bounds[:-1], self.bounds[1:])):
                try:
                    conn.send((err, None if control is None else control.worlds(lo, hi)))
                except (BrokenPipeError, OSError):
                    failures.append(self._worlds(k) + " died")
            for k, conn in enumerate(self._conns):
                try:
                    kind, payload = conn.recv()
                except (EOFError, OSError):
                    failures.append(self._worlds(k) + " died")
                    continue
                if kind == "error":
                    failures.append(f"{self._worlds(k)}: {payload}")
                    continue
                events += payload
                nonfinite |= kind == "nonfinite"
        except BaseException:
            self.close()  # a reply left unread would answer the next step
            raise
        if failures:
            self.close()
            raise RuntimeError("parallel step failed: " + "; ".join(failures))
        self.state.events = events
        if nonfinite:
            raise _nonfinite_error(self.model, self.state, self.state.nonfinite_worlds())
        return self.state

    def close(self) -> None:
        """Stop the workers. The state's arrays stay where they are (shared
        memory that lives as long as they do) and keep their values."""
        for conn in self._conns:
            try:
                conn.send("stop")
            except (BrokenPipeError, OSError):
                pass
        for p in self._procs:
            p.join(timeout=5)
            if p.is_alive():
                p.kill()
                p.join()
        for conn in self._conns:
            conn.close()
        self._conns, self._procs = [], []

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def __del__(self):
        try:
            self.close()
        except Exception:
            pass


def _share(state: State) -> None:
    """Move every array of ``state`` into one anonymous shared mapping, in
    place. Forked workers inherit it; the arrays keep the mapping alive, so
    it is freed with the last of them and nothing needs unlinking."""
    offsets, total = {}, 0
    for k, v in state.arrays.items():
        offsets[k] = total
        total += -(-v.nbytes // _ALIGN) * _ALIGN
    block = mmap.mmap(-1, max(total, 1))  # MAP_SHARED | MAP_ANONYMOUS
    for k, v in list(state.arrays.items()):
        shared = np.frombuffer(block, dtype=v.dtype, count=v.size, offset=offsets[k]).reshape(v.shape)
        shared[...] = v
        state.arrays[k] = shared


def _worker(conn, model, state, lo, hi):
    """Step worlds [lo, hi) of ``state`` (views of the shared arrays) on each
    (numpy error state, control) received, until "stop" or the parent's end
    of the pipe closes. Ctrl-C reaches the whole process group; the parent
    alone handles it (and closes the workers), so a worker ignores SIGINT
    rather than die mid-step with a traceback of its own."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})  # blocked by the parent while forking
    part = state.worlds(lo, hi)
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):
            return
        if isinstance(msg, str) and msg == "stop":
            return
        err, control = msg
        try:
            with np.errstate(**err):
                step(model, part, control)
            conn.send(("ok", shift_worlds(part.events, lo)))
        except SimulationError:
            conn.send(("nonfinite", shift_worlds(part.events, lo)))
        except Exception as exc:  # reported by the parent, which closes the pool
            conn.send(("error", f"{type(exc).__name__}: {exc}"))
