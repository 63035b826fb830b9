"""Helpers shared by the benchmarks: timing medians, tables and JSON output.

A measurement is described by ``make_run(n)``: untimed setup for ``n`` steps
that returns a callable doing the timed work. ``measure`` warms up, picks a
step count (unless given) so one repeat takes about ``target_s`` seconds, and
returns the median wall time of the repeats, taken with ``time.perf_counter``.
"""

from __future__ import annotations

import json
import math
import os
import statistics
import time


def timed(run) -> float:
    t0 = time.perf_counter()
    run()
    return time.perf_counter() - t0


def median_seconds(make_run, steps: int, repeats: int) -> float:
    return statistics.median(timed(make_run(steps)) for _ in range(repeats))


def calibrate(make_run, target_s: float, min_steps: int = 1, max_steps: int = 1_000_000) -> int:
    """Steps that make one run last about ``target_s`` seconds (doubling from 1)."""
    n = 1
    while True:
        t = timed(make_run(n))
        if t >= target_s / 8 or n >= max_steps:
            break
        n *= 2
    return int(min(max(math.ceil(n * target_s / max(t, 1e-9)), min_steps), max_steps))


def measure(make_run, repeats: int, steps: int | None = None, target_s: float = 1.0,
            min_steps: int = 1, max_steps: int = 1_000_000) -> tuple[int, float]:
    """Warm up, then return (steps per repeat, median seconds per repeat)."""
    make_run(1)()
    if steps is None:
        steps = calibrate(make_run, target_s, min_steps, max_steps)
    return steps, median_seconds(make_run, steps, repeats)


def format_value(x) -> str:
    if x is None:
        return "-"
    if isinstance(x, float):
        if x == 0 or not math.isfinite(x):
            return f"{x:g}"
        return f"{x:,.0f}" if abs(x) >= 1000 else f"{x:.3g}"
    return str(x)


def print_table(rows, columns, title: str | None = None) -> None:
    """Print ``rows`` (dicts) as a text table; ``columns`` is a list of
    (header, key or function of the row). Text columns are left-aligned."""
    cells = [[format_value(get(r) if callable(get) else r.get(get)) for _, get in columns] for r in rows]
    headers = [h for h, _ in columns]
    widths = [max([len(h)] + [len(c[i]) for c in cells]) for i, h in enumerate(headers)]
    left = [all(not _numeric(c[i]) for c in cells) for i in range(len(headers))]

    def line(values):
        return "  ".join(v.ljust(w) if l else v.rjust(w) for v, w, l in zip(values, widths, left)).rstrip()

    if title:
        print(title)
    print(line(headers))
    print(line(["-" * w for w in widths]))
    for c in cells:
        print(line(c))


def _numeric(text: str) -> bool:
    try:
        float(text.replace(",", ""))
        return True
    except ValueError:
        return text == "-"


def machine_note() -> str:
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    return f"machine: {os.cpu_count()} CPUs, 1-min load average {load:.2f} at the end of the run"


def write_json(path: str, rows) -> None:
    directory = os.path.dirname(os.path.abspath(path))
    os.makedirs(directory, exist_ok=True)
    with open(path, "w", encoding="utf-8") as f:
        json.dump(rows, f, indent=2)
        f.write("\n")
