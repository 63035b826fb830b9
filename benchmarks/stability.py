"""Hard cases: do they stay numerically stable?

    python -m benchmarks.stability [--quick] [--json PATH] [--case NAME ...] [--list]
        [--settings JSON]

Runs each hard-case scene of :mod:`benchmarks.scenes` for its stated time
(``--quick``: the shortened duration the fast tests use; the random-torque
ragdoll runs 2,000 steps instead of 100,000) and prints per case:

* ``v_end``: the largest body speed at the end, m/s;
* ``dE``: the largest energy rise above the start plus the motors' work,
  max over steps of E(t) - E(0) - W_motor(t), in J and relative to |E(0)|
  (potentials measured in the scene's own frame; see benchmarks.scenes);
* ``tol``: the energy tolerance the test holds the case to (J);
* ``anchor``: the largest joint anchor error over the run, m;
* ``pen``: the deepest penetration over the run, m (-min of the valid
  ``state.contact_separation`` entries); ``pen_late``: from the case's
  ``penetration_after`` on (overlap scenes start overlapped);
* ``v_rest``: the largest speed from the case's rest time on, m/s;
  ``v_max``: the largest speed at any step, m/s;
* ``nan``: whether a NaN/inf appeared; ``wall``: wall time, s.
"""

from __future__ import annotations

import argparse
import math
import sys

from .common import machine_note, print_table, settings_json, write_json
from .scenes import case_names, make_case, run_case


def _fmt(x, digits=3):
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "-"
    return f"{x:.{digits}g}"


def parse_args(argv=None):
    """The options, checked (unknown cases, bad --settings: a usage error)."""
    p = argparse.ArgumentParser(prog="python -m benchmarks.stability", description=__doc__.split("\n")[0])
    p.add_argument("--quick", action="store_true", help="shortened durations (as the fast tests)")
    p.add_argument("--json", metavar="PATH", help="write the results as JSON")
    p.add_argument("--case", nargs="+", metavar="NAME", help="only these cases")
    p.add_argument("--list", action="store_true", help="list the cases and exit")
    p.add_argument("--settings", metavar="JSON", type=settings_json, default={},
                   help='engine settings (engine.Settings fields) over each case\'s own, e.g. '
                        '\'{"substeps": 8}\' (Infinity for inf)')
    args = p.parse_args(argv)
    if args.case:
        names = case_names()
        unknown = [n for n in args.case if n not in names]
        if unknown:
            p.error(f"unknown case(s) {unknown}; cases: {names}")
    return args


def main(argv=None) -> int:
    args = parse_args(argv)
    names = case_names()
    if args.list:
        print("\n".join(names))
        return 0
    if args.case:
        names = args.case
    rows = []
    for name in names:
        case = make_case(name)
        if args.settings:
            case.model = case.model.with_settings(**args.settings)
        r = run_case(case, quick=args.quick)
        row = r.row()
        row.update(energy_tol=case.energy_tol, anchor_bound=case.anchor_bound,
                   penetration_bound=case.penetration_bound, rest_time=case.rest_time,
                   rest_speed=case.rest_speed, speed_bound=case.speed_bound, dt=case.dt,
                   description=case.description)
        rows.append(row)
        print(f"{name:28s} {r.steps:6d} steps  {r.wall_time:7.1f} s", file=sys.stderr, flush=True)
    columns = [
        ("case", "name"),
        ("t (s)", lambda r: _fmt(r["sim_time"])),
        ("v_end", lambda r: _fmt(r["max_speed_end"])),
        ("dE (J)", lambda r: _fmt(r["energy_rise"])),
        ("dE/|E0|", lambda r: _fmt(r["energy_rise_rel"])),
        ("tol (J)", lambda r: _fmt(r["energy_tol"])),
        ("W_motor", lambda r: _fmt(r["motor_work"])),
        ("anchor (m)", lambda r: _fmt(r["max_anchor_error"])),
        ("pen (m)", lambda r: _fmt(r["max_penetration"])),
        ("pen_late", lambda r: _fmt(r["max_penetration_after"])),
        ("v_rest", lambda r: _fmt(r["rest_speed_max"])),
        ("v_max", lambda r: _fmt(r["max_speed_all"])),
        ("v_fling", lambda r: _fmt(r["max_fling_speed"])),
        ("nan", lambda r: "yes" if r["nan"] else "no"),
        ("wall (s)", lambda r: _fmt(r["wall_time"])),
    ]
    print_table(rows, columns, title=f"stability ({'quick' if args.quick else 'full'} durations)")
    print(machine_note())
    if args.json:
        write_json(args.json, rows)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
