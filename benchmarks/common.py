"""Helpers shared by the benchmarks: timing medians, tables, JSON output and
argument checks.

A measurement is described by ``make_run(n)``: untimed setup for ``n`` steps
that returns a callable doing the timed work. ``measure`` warms up, picks a
step count (unless given) so one repeat takes about ``target_s`` seconds, and
returns the median wall time of the repeats, taken with ``time.perf_counter``.

``positive_int``, ``nonnegative_int``, ``positive_float`` and
``settings_json`` are argparse ``type=`` functions: a bad value is a usage
error naming the option, not a traceback from inside a run.
"""

from __future__ import annotations

import argparse
import difflib
import json
import math
import os
import statistics
import time
from dataclasses import fields, replace


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


# ------------------------------------------------------------ argument checks
# (ragdoll_env.cli_args has the same integer types for the env and training CLIs;
# importing it here would import gymnasium into the engine-only benchmarks.)
def positive_int(text: str) -> int:
    """argparse type: an integer >= 1."""
    return _int_at_least(text, 1)


def nonnegative_int(text: str) -> int:
    """argparse type: an integer >= 0."""
    return _int_at_least(text, 0)


def _int_at_least(text: str, low: int) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer >= {low}, got {text!r}") from None
    if value < low:
        raise argparse.ArgumentTypeError(f"must be an integer >= {low}, got {text!r}")
    return value


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number > 0, got {text!r}") from None
    if not (value > 0 and math.isfinite(value)):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text!r}")
    return value


def settings_json(text: str) -> dict:
    """argparse type: a JSON object of ``engine.Settings`` fields and values
    (``Infinity`` for inf), checked as ``Settings`` checks them, so a
    misspelt name or a bad value stops the command before anything runs."""
    from engine.settings import Settings

    example = """'{"substeps": 8}'"""
    try:
        value = json.loads(text)
    except json.JSONDecodeError as exc:
        raise argparse.ArgumentTypeError(f"not valid JSON ({exc}): {text!r}; e.g. {example}") from None
    if not isinstance(value, dict):
        raise argparse.ArgumentTypeError(f"must be a JSON object of setting names and values, e.g. {example}; "
                                         f"got {text!r}")
    defaults = Settings()
    names = [f.name for f in fields(Settings)]
    unknown = [k for k in value if k not in names]
    if unknown:
        hints = [f"{k!r} (did you mean {close[0]!r}?)" if (close := difflib.get_close_matches(k, names, n=1))
                 else repr(k) for k in unknown]
        raise argparse.ArgumentTypeError(f"unknown setting{'s' if len(unknown) > 1 else ''} {', '.join(hints)}; "
                                         f"settings: {', '.join(names)}")
    for name, v in value.items():
        default = getattr(defaults, name)
        if default is None:  # a flag whose default is "on wherever it can act"
            ok, want = v is None or isinstance(v, bool), "true, false or null (on wherever it can act)"
        elif isinstance(default, bool):
            ok, want = isinstance(v, bool), "true or false"
        elif isinstance(default, int):
            ok, want = isinstance(v, int) and not isinstance(v, bool), "an integer"
        elif isinstance(default, float):
            ok, want = isinstance(v, (int, float)) and not isinstance(v, bool), "a number (Infinity for inf)"
        elif isinstance(default, str):
            ok, want = isinstance(v, str), "a string"
        else:
            ok, want = True, ""
        if not ok:
            raise argparse.ArgumentTypeError(f"setting {name!r} must be {want}, got {json.dumps(v)}")
    try:
        replace(defaults, **value).validate()
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc).removeprefix("settings: ")) from None
    return value
