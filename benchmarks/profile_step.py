"""Where a step's time goes inside the compiled kernels: a sampling profile
with the kernels' own names, and who calls numba's reference counting.

    python -m benchmarks.profile_step [--worlds 64] [--threads 1] [--seconds 15] [--json PATH]

Steps the humanoid lying on the ground (``benchmarks.throughput``'s
``ragdoll_ground`` under its random torques) while Linux ``perf`` samples the
process, then prints the share of samples in each function. numba's machine
code has no symbols perf can see, so before stepping this writes
``/tmp/perf-PID.map`` (perf's map of JIT code) from the object code of every
kernel loaded from the cache. Samples in ``NRT_incref``/``NRT_decref`` (the
atomic reference counts numba makes for every array a call or a view takes)
are charged to the kernel that called them, read from the sample's stack.

Needs ``perf`` (linux-tools) and ``pyelftools`` (the ``dev`` extra). Run it
on a warm cache: a kernel compiled in this process instead of loaded is not
in the map (its samples show as ``?``).
"""

from __future__ import annotations

import argparse
import bisect
import collections
import json
import os
import re
import shutil
import struct
import subprocess
import sys
import tempfile
import time
from io import BytesIO

import numba.core.codegen as _codegen

# numba hands its JIT engine this hook when the CPU target starts (before
# any kernel loads, so before engine is imported): wrapped here to keep the
# object code of each kernel loaded from the cache, for its symbol table
# (numba drops it once loaded), while keep_object_code() has asked for it.
_OBJECTS = []
_KEEP = [False]
_load_object = _codegen.CPUCodeLibrary._object_getbuffer_hook.__func__


def _keep_object(cls, ll_module):
    buf = _load_object(cls, ll_module)
    if buf and _KEEP[0]:
        _OBJECTS.append(buf)
    return buf


_codegen.CPUCodeLibrary._object_getbuffer_hook = classmethod(_keep_object)

import numpy as np  # noqa: E402

from engine import set_threads, step  # noqa: E402

from .common import positive_float, positive_int  # noqa: E402
from .throughput import random_controls, ragdoll, thread_count  # noqa: E402

NRT = ("NRT_incref", "NRT_decref")


def keep_object_code():
    """Keep the object code of the kernels loaded from now on (they load at
    their first call, so this comes before the first step)."""
    _KEEP[0] = True


def short_name(symbol: str) -> str:
    """``engine.core.tree.factor`` from numba's mangled ``_ZN6engine4core4tree6factorB...``."""
    prefix = ""
    if symbol.startswith("cfunc."):
        prefix, symbol = "cfunc.", symbol[6:]
    i = symbol.find("_ZN")
    if i < 0:
        return prefix + symbol[:80]
    rest, parts = symbol[i + 3:], []
    while rest and rest[0].isdigit():
        digits = re.match(r"\d+", rest).group(0)
        n = int(digits)
        parts.append(rest[len(digits):len(digits) + n])
        rest = rest[len(digits) + n:]
    return prefix + ".".join(parts)


def write_perf_map() -> dict:
    """Write /tmp/perf-PID.map for the loaded kernels; returns {address: (name, size)}."""
    from elftools.elf.elffile import ELFFile
    from numba.core.registry import cpu_target

    engine = cpu_target.target_context.codegen()._engine
    symbols = {}
    for obj in _OBJECTS:
        table = ELFFile(BytesIO(obj)).get_section_by_name(".symtab")
        for sym in table.iter_symbols():
            if sym["st_info"]["type"] != "STT_FUNC" or sym["st_size"] == 0:
                continue
            address = engine.get_function_address(sym.name)
            if address:
                symbols[address] = (short_name(sym.name), sym["st_size"])
    with open(f"/tmp/perf-{os.getpid()}.map", "w") as f:
        for address in sorted(symbols):
            name, size = symbols[address]
            f.write(f"{address:x} {size:x} {name}\n")
    return symbols


class Symbols:
    """Address -> kernel name lookups in the map of ``write_perf_map``."""

    def __init__(self, symbols):
        self.starts = sorted(symbols)
        self.entries = [symbols[a] for a in self.starts]

    def name(self, address):
        i = bisect.bisect_right(self.starts, address) - 1
        if i >= 0 and address < self.starts[i] + self.entries[i][1]:
            return self.entries[i][0]
        return None


def samples(perf_data):
    """(ip, dso, first stack words) of each sample, from ``perf script -D``."""
    p = subprocess.Popen(["perf", "script", "-i", perf_data, "-D"], stdout=subprocess.PIPE,
                         stderr=subprocess.DEVNULL, text=True)
    raw, in_raw, ip, pending = bytearray(), False, None, None
    for line in p.stdout:
        if line.startswith(". ... raw event"):
            raw, in_raw = bytearray(), True
            continue
        if in_raw and line.startswith(".  "):
            raw += bytes(int(t, 16) for t in line[9:].split("  ")[0].split())
            continue
        in_raw = False
        m = re.search(r"PERF_RECORD_SAMPLE\(IP, 0x2\): \d+/\d+: (0x[0-9a-f]+)", line)
        if m:
            ip = int(m.group(1), 16)
            continue
        m = re.match(r"\.\.\. ustack: size (\d+), offset (0x[0-9a-f]+)", line)
        if m and ip is not None:
            at = int(m.group(2), 16)
            count = max(0, min(64, (len(raw) - at) // 8))  # the 512 bytes of stack perf copies
            words = [struct.unpack_from("<Q", raw, at + 8 * k)[0] for k in range(count)]
            pending = (ip, words)
            continue
        m = re.match(r" \.\.\.\.\.\. dso: (.*)", line)
        if m and pending:
            yield pending[0], m.group(1).split("/")[-1], pending[1]
            pending, ip = None, None
    p.wait()


def profile(worlds, threads, seconds, frequency=999, callers_of=()):
    if shutil.which("perf") is None:
        raise SystemExit("profile_step needs Linux perf (linux-tools) on PATH")
    keep_object_code()
    set_threads(threads)
    model = ragdoll(ground=True)
    settle = model.initial_state(8)
    controls = random_controls(model, 8, seed=1)
    for i in range(120):
        step(model, settle, controls[i % len(controls)])
    state = settle.select(np.arange(worlds) % 8)
    controls = random_controls(model, worlds)
    for i in range(20):  # every kernel loaded before the map is written
        step(model, state, controls[i % len(controls)])
    symbols = Symbols(write_perf_map())
    out = os.path.join(tempfile.mkdtemp(), "perf.data")
    rec = subprocess.Popen(["perf", "record", "-q", "-F", str(frequency), "--call-graph", "dwarf,512", "-p",
                            str(os.getpid()), "-o", out, "--", "sleep", str(seconds)],
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    n, t0 = 0, time.perf_counter()
    while rec.poll() is None:
        step(model, state, controls[n % len(controls)])
        n += 1
    elapsed = time.perf_counter() - t0
    own, nrt_callers, total = collections.Counter(), collections.Counter(), 0
    callers = {name: collections.Counter() for name in callers_of}
    for ip, dso, words in samples(out):
        total += 1
        name = symbols.name(ip) or dso
        own[name] += 1
        if name in NRT or name in callers:
            # The first kernel other than itself whose code a word of the
            # sample's top of stack points into: a return address, its caller
            # (a guess: a leaf's saved registers can hide it, "?").
            caller = next((c for c in map(symbols.name, words) if c and c not in NRT and c != name), "?")
            (nrt_callers if name in NRT else callers[name])[caller] += 1
    return {"worlds": worlds, "threads": threads, "steps": n, "us_per_world_step": elapsed / (n * worlds) * 1e6,
            "samples": total, "self": dict(own.most_common()), "nrt_by_caller": dict(nrt_callers.most_common()),
            "callers": {k: dict(v.most_common()) for k, v in callers.items()}}


def parse_args(argv):
    ap = argparse.ArgumentParser(prog="python -m benchmarks.profile_step", description=__doc__.split("\n\n")[0])
    ap.add_argument("--worlds", type=positive_int, default=64, help="worlds stepped together (default 64)")
    ap.add_argument("--threads", type=thread_count, default=1, help="threads (default 1)")
    ap.add_argument("--seconds", type=positive_float, default=15.0, help="seconds sampled (default 15)")
    ap.add_argument("--top", type=positive_int, default=30, help="functions listed (default 30)")
    ap.add_argument("--callers", nargs="+", default=(), metavar="KERNEL",
                    help="also attribute these kernels' samples to their callers "
                         "(full names, e.g. engine.core.tree.solve_nodes)")
    ap.add_argument("--json", metavar="PATH", help="write the result here")
    return ap.parse_args(argv)


def main(argv=None):
    args = parse_args(argv)
    r = profile(args.worlds, args.threads, args.seconds, callers_of=tuple(args.callers))
    total = max(r["samples"], 1)
    print(f"W={r['worlds']} threads={r['threads']}: {r['us_per_world_step']:.0f} us per world-step under "
          f"the profiler, {r['samples']} samples")
    print(f"{'self %':>7}  function")
    for name, count in list(r["self"].items())[:args.top]:
        print(f"{100 * count / total:7.1f}  {name}")
    nrt = sum(r["self"].get(k, 0) for k in NRT)
    print(f"\nreference counting {100 * nrt / total:.1f}% of samples, by calling kernel:")
    for name, count in list(r["nrt_by_caller"].items())[:15]:
        print(f"{100 * count / total:7.1f}  {name}")
    for name, by in r["callers"].items():
        print(f"\n{name}: {100 * r['self'].get(name, 0) / total:.1f}% of samples, by calling kernel:")
        for caller, count in list(by.items())[:10]:
            print(f"{100 * count / total:7.1f}  {caller}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(r, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
