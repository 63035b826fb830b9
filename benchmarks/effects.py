"""What each effect costs: step time with the effect switched on and off.

    python -m benchmarks.effects [--worlds 1 256] [--scenes ...] [--steps N] [--repeats R]
        [--target-seconds S] [--settle-steps N] [--quick] [--json PATH] [--markdown PATH]

Scenes: ``inverted_pendulum`` (a pole on an actuated hinge to the world, no
ground), ``ragdoll_ground``, ``ragdoll_air`` and ``box_pile`` (12 boxes on the
floor). Per scene the baseline is built with the effects it naturally has;
each other row changes one effect: switched off by the builder
(``SceneBuilder(gravity=None)``, ``disable("friction")``, ...), built without
it (no ground, no limits, zero-restitution materials, max_torque 0), or
switched on (``enable("self_collision")``, ``enable("gravitation")``, body
damping, springs). ``model.effect_names`` is printed per row: an effect absent
from it runs no code. The baseline is measured again at the end of each scene
as a noise check. JSON rows: {scene, variant, how, effects (name -> bool),
effect_names, worlds, step_s, ratio_to_baseline, steps, repeats}.

Every variant starts from its scene after 0.2 s of simulation (one world,
copied to W), runs the same number of steps as the scene's baseline, and the
timed repeats go round the variants in turn, so load drift hits all alike.
"""

from __future__ import annotations

import argparse
import statistics
from dataclasses import replace

import numpy as np

import engine as e

from . import scenarios as sc
from .common import (calibrate, machine_note, nonnegative_int, positive_float, positive_int, print_table, timed,
                     write_json)
from .throughput import random_controls

EFFECTS = ("gravity", "springs", "damping", "motors", "contacts", "friction", "restitution", "joint_limits",
           "self_collision", "gravitation")
DEFAULT_WORLDS = (1, 256)
QUICK_WORLDS = (1, 8)

BASE = {
    "inverted_pendulum": dict(gravity=True, motors=True, joint_limits=True),
    "ragdoll_ground": dict(gravity=True, motors=True, joint_limits=True, contacts=True, friction=True,
                           restitution=True),
    "ragdoll_air": dict(gravity=True, motors=True, joint_limits=True),
    "box_pile": dict(gravity=True, contacts=True, friction=True, restitution=True),
}

# (variant label, how, changes to the baseline flags, extra build option)
VARIANTS = {
    "inverted_pendulum": [
        ("no gravity (gravity=None)", "built without", {"gravity": False}, None),
        ("gravity disabled", "switched off", {"gravity": False}, "disable"),
        ("no motor", "built without", {"motors": False}, None),
        ("no limits", "built without", {"joint_limits": False}, None),
        ("+ damping", "switched on", {"damping": True}, None),
        ("+ spring", "switched on", {"springs": True}, None),
        ("+ ground contact", "switched on", {"contacts": True, "friction": True, "restitution": True}, None),
        ("+ gravitation", "switched on", {"gravitation": True}, None),
    ],
    "ragdoll_ground": [
        ("no gravity (gravity=None)", "built without", {"gravity": False}, None),
        ("gravity disabled", "switched off", {"gravity": False}, "disable"),
        ("no motors", "built without", {"motors": False}, None),
        ("no limits", "built without", {"joint_limits": False}, None),
        ("no ground", "built without", {"contacts": False, "friction": False, "restitution": False}, None),
        ("contacts disabled", "switched off", {"contacts": False, "friction": False, "restitution": False},
         "disable"),
        ("friction disabled", "switched off", {"friction": False}, "disable"),
        ("restitution disabled", "switched off", {"restitution": False}, "disable"),
        ("zero-restitution materials", "built without", {"restitution": False}, None),
        ("+ damping", "switched on", {"damping": True}, None),
        ("+ damping, disabled", "switched off", {"damping": False}, "damping_disabled"),
        ("+ springs", "switched on", {"springs": True}, None),
        ("+ self_collision", "switched on", {"self_collision": True}, None),
        ("+ gravitation", "switched on", {"gravitation": True}, None),
    ],
    "ragdoll_air": [
        ("no gravity (gravity=None)", "built without", {"gravity": False}, None),
        ("no motors", "built without", {"motors": False}, None),
        ("no limits", "built without", {"joint_limits": False}, None),
        ("+ damping", "switched on", {"damping": True}, None),
        ("+ springs", "switched on", {"springs": True}, None),
        ("+ self_collision", "switched on", {"contacts": True, "self_collision": True}, None),
        ("+ gravitation", "switched on", {"gravitation": True}, None),
    ],
    "box_pile": [
        ("no gravity (gravity=None)", "built without", {"gravity": False}, None),
        ("no ground", "built without", {"contacts": False, "friction": False, "restitution": False}, None),
        ("contacts disabled", "switched off", {"contacts": False, "friction": False, "restitution": False},
         "disable"),
        ("friction disabled", "switched off", {"friction": False}, "disable"),
        ("restitution disabled", "switched off", {"restitution": False}, "disable"),
        ("zero-restitution materials", "built without", {"restitution": False}, None),
        ("+ damping", "switched on", {"damping": True}, None),
        ("+ springs", "switched on", {"springs": True}, None),
        ("+ gravitation", "switched on", {"gravitation": True}, None),
    ],
}


def _zero_restitution_materials():
    table = e.MaterialTable()
    return e.MaterialTable({k: replace(m, restitution=0.0) for k, m in table.materials.items()}, table.pairs)


def build(scene, flags, option=None):
    """The scene's model with the effects in ``flags``; ``option`` chooses how
    an absent effect is absent ("disable": built with it, then
    ``builder.disable``; "damping_disabled": bodies get damping, then
    ``disable("damping")``; None: built without it)."""
    kw = {}
    if not flags.get("gravity") and option != "disable":
        kw["gravity"] = None
    if not flags.get("restitution") and flags.get("contacts") and option != "disable":
        kw["materials"] = _zero_restitution_materials()
    ground = scene != "ragdoll_air" and (flags.get("contacts") or (option == "disable" and scene in
                                                                    ("ragdoll_ground", "box_pile")))
    if scene == "inverted_pendulum":
        b = sc.inverted_pendulum(ground=bool(flags.get("contacts")), **kw)
        springs = [("pole", None, (0.3, 0.0, 1.0))]
    elif scene in ("ragdoll_ground", "ragdoll_air"):
        b, _ = sc.ragdoll(ground=bool(ground), height=0.0 if scene == "ragdoll_ground" else 1.0, **kw)
        springs = [("pelvis", None, (0.0, 0.0, 2.5)), ("lower_arm_l", None, (0.5, 1.0, 2.0)),
                   ("lower_arm_r", None, (0.5, -1.0, 2.0))]
    else:
        b = sc.box_pile(ground=bool(ground), **kw)
        springs = [(f"box_{i}", f"box_{i + 1}", None) for i in range(0, 11, 2)]
    if not flags.get("motors"):
        for j in b.joints:
            j.max_torque = np.zeros(3)
    if not flags.get("joint_limits"):
        for j in b.joints:
            j.limits = {}
    if flags.get("damping") or option == "damping_disabled":
        for body in b.bodies:
            if not body.static:
                body.linear_damping, body.angular_damping = 0.05, 0.05
        b.enable("damping")
    if flags.get("springs"):
        for k, (a, other, anchor) in enumerate(springs):
            b.add_spring(f"spring_{k}", a, other, anchor_b=anchor, stiffness=200.0, damping=2.0)
    if flags.get("self_collision"):
        if "contacts" not in b.effects:
            b.enable("contacts")
            for implied in ("friction", "restitution"):  # the scene's flags decide these
                if not flags.get(implied):
                    b.disable(implied)
        b.enable("self_collision")
    if flags.get("gravitation"):
        b.enable("gravitation", G=1e-3, softening=0.05)
    if option == "disable":
        for name in ("gravity", "contacts", "friction", "restitution"):
            if not flags.get(name):
                b.disable(name)
    if option == "damping_disabled":
        b.disable("damping")
    return b.build()


SETTLE_STEPS = 12  # 0.2 s: dropped bodies reach the floor before timing starts


def settled_state(model, worlds, controls, settle_steps=SETTLE_STEPS):
    """The scene after SETTLE_STEPS steps of one world, copied to ``worlds`` worlds,
    so every variant is timed in the same phase (contacts made) whatever its step count."""
    s = model.initial_state(1)
    for i in range(settle_steps):
        c = controls[i % len(controls)]
        e.step(model, s, None if c is None else e.Control(motor=c.motor[:1]))
    return s.select(np.zeros(worlds, dtype=np.int64))


def make_runner(model, worlds, with_control=True, settle_steps=SETTLE_STEPS):
    controls = random_controls(model, worlds) if with_control else [None]
    state0 = settled_state(model, worlds, controls, settle_steps)

    def make_run(n):
        state = state0.copy()

        def run():
            for i in range(n):
                e.step(model, state, controls[i % len(controls)])
        return run
    return make_run


def scene_rows(scene, worlds, args):
    """Every variant of a scene timed with the same step count, the repeats
    interleaved across variants so that machine-load drift hits all alike."""
    base = {k: bool(BASE[scene].get(k, False)) for k in EFFECTS}
    variants = [("baseline", "baseline", {}, None)] + VARIANTS[scene] + [("baseline (again)", "baseline", {}, None)]
    built = []
    for label, how, changes, option in variants:
        flags = dict(base, **changes)
        model = build(scene, flags, option)
        built.append((label, how, flags, model, make_runner(model, worlds, flags["motors"], args.settle_steps)))
    first = built[0][4]
    first(1)()  # warm-up
    steps = args.steps or calibrate(first, args.target_seconds, min_steps=2)
    times = [[] for _ in built]
    for _ in range(args.repeats):
        for k, b in enumerate(built):
            times[k].append(timed(b[4](steps)))
    rows = []
    for (label, how, flags, model, _), ts in zip(built, times):
        rows.append({"scene": scene, "variant": label, "how": how, "effects": flags,
                     "effect_names": list(model.effect_names), "worlds": worlds,
                     "step_s": statistics.median(ts) / steps, "steps": steps, "repeats": args.repeats})
    ref = rows[0]["step_s"]
    for r in rows:
        r["ratio_to_baseline"] = r["step_s"] / ref
    return rows


def summary_lines(rows):
    lines = []
    for w in sorted({r["worlds"] for r in rows}):
        def base(scene):
            return next((r for r in rows if r["scene"] == scene and r["worlds"] == w and r["how"] == "baseline"), None)
        p, g = base("inverted_pendulum"), base("ragdoll_ground")
        if p and g:
            lines.append(f"W={w}: inverted_pendulum step / ragdoll_ground step = "
                         f"{p['step_s'] / g['step_s']:.3f} ({p['step_s'] * 1e3:.3g} ms vs {g['step_s'] * 1e3:.3g} ms)")
        pairs = [("ragdoll_ground", "gravity disabled", "no gravity (gravity=None)"),
                 ("inverted_pendulum", "gravity disabled", "no gravity (gravity=None)"),
                 ("ragdoll_ground", "contacts disabled", "no ground"),
                 ("box_pile", "contacts disabled", "no ground"),
                 ("ragdoll_ground", "restitution disabled", "zero-restitution materials"),
                 ("box_pile", "restitution disabled", "zero-restitution materials"),
                 ("ragdoll_ground", "+ damping, disabled", "baseline")]
        for scene, a, b in pairs:
            ra = next((r for r in rows if r["scene"] == scene and r["worlds"] == w and r["variant"] == a), None)
            rb = next((r for r in rows if r["scene"] == scene and r["worlds"] == w and r["variant"] == b), None)
            if ra and rb:
                same = "same" if ra["effect_names"] == rb["effect_names"] else "DIFFERENT"
                lines.append(f"W={w} {scene}: '{a}' / '{b}' = {ra['step_s'] / rb['step_s']:.3f} "
                             f"({same} effect_names)")
        again = [r for r in rows if r["worlds"] == w and r["variant"] == "baseline (again)"]
        if again:
            lines.append(f"W={w} noise: baseline measured twice differs by "
                         + ", ".join(f"{r['scene']} {abs(r['ratio_to_baseline'] - 1) * 100:.1f}%" for r in again))
    return lines


COLUMNS = [("scene", "scene"), ("W", "worlds"), ("variant", "variant"), ("how", "how"),
           ("step ms", lambda r: r["step_s"] * 1e3), ("x baseline", "ratio_to_baseline"),
           ("effect_names", lambda r: " ".join(r["effect_names"]))]


def markdown(rows, lines):
    out = ["# Effect costs", "", "Written by `python -m benchmarks.effects`. Median seconds per step "
           "(all W worlds in one call); `x baseline` is the ratio to the scene's baseline in the same run. "
           "`effect_names` is what the compiled model runs.", ""]
    head = [h for h, _ in COLUMNS]
    out.append("| " + " | ".join(head) + " |")
    out.append("|" + "---|" * len(head))
    from .common import format_value

    for r in rows:
        out.append("| " + " | ".join(format_value(g(r) if callable(g) else r[g]) for _, g in COLUMNS) + " |")
    out += [""] + [f"- {l}" for l in lines] + ["", machine_note()]
    return "\n".join(out) + "\n"


def parse_args(argv):
    p = argparse.ArgumentParser(prog="python -m benchmarks.effects", description=__doc__.split("\n")[0])
    p.add_argument("--worlds", type=positive_int, nargs="+", help="world counts (default 1 256)")
    p.add_argument("--scenes", nargs="+", choices=list(BASE), default=list(BASE))
    p.add_argument("--steps", type=positive_int, help="steps per timed repeat (default: enough for --target-seconds)")
    p.add_argument("--repeats", type=positive_int, help="timed repeats, the median is reported (default 5)")
    p.add_argument("--target-seconds", type=positive_float, default=0.3,
                   help="wall time per repeat when --steps is not given (default 0.3)")
    p.add_argument("--settle-steps", type=nonnegative_int, help=f"steps of one world before timing (default {SETTLE_STEPS})")
    p.add_argument("--quick", action="store_true", help="W = 1 8, 3 steps, 2 repeats, 1 settle step: a smoke test")
    p.add_argument("--json", metavar="PATH", help="write the rows as a JSON list")
    p.add_argument("--markdown", metavar="PATH", help="write the table as markdown (e.g. docs/effects.md)")
    args = p.parse_args(argv)
    if args.quick:
        args.worlds = args.worlds or list(QUICK_WORLDS)
        args.steps = args.steps or 3
        args.repeats = args.repeats or 2
        args.settle_steps = 1 if args.settle_steps is None else args.settle_steps
    args.worlds = args.worlds or list(DEFAULT_WORLDS)
    args.repeats = args.repeats or 5
    args.settle_steps = SETTLE_STEPS if args.settle_steps is None else args.settle_steps
    return args


def main(argv=None):
    args = parse_args(argv)
    rows = []
    for w in args.worlds:
        for scene in args.scenes:
            rows += scene_rows(scene, w, args)
            print(f"measured {scene} W={w}", flush=True)
    print()
    print_table(rows, COLUMNS, title="Step cost per effect (median of repeats)")
    print(machine_note())
    lines = summary_lines(rows)
    for line in lines:
        print(line)
    if args.markdown:
        import os

        os.makedirs(os.path.dirname(os.path.abspath(args.markdown)), exist_ok=True)
        with open(args.markdown, "w", encoding="utf-8") as f:
            f.write(markdown(rows, lines))
        print(f"wrote {args.markdown}")
    if args.json:
        write_json(args.json, rows)
        print(f"wrote {args.json}")
    return rows


if __name__ == "__main__":
    main()
