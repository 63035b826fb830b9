"""Compile the step's kernels into numba's cache ahead of use.

    python -m engine.warmup

steps a few small scenes that between them reach every kernel on the
default path and the other integrators (a humanoid on the ground with its
motors, boxes, spheres and capsules on the ground, springs and universal
gravitation), the Gauss-Seidel joint rows (``joint_solver="gauss_seidel"``:
point, hinge and fixed locks, limits, breaking), the thesis's solver
(``solver="thesis"``: its position corrections of joints and contacts),
restitution (free and jointed bodies landing on rubber) and the static
contact projection (a box and a humanoid's feet deep in the ground, greedy
contact colouring), for one world and for a batch, and calls the
numpy-facing collision functions for every pair kind and the merge of the
projection's rounds. The machine code lands in
numba's cache (``cache=True``: next to the sources, or under
``NUMBA_CACHE_DIR``), so a later process starts stepping at once. CI runs it
once before the tests.
"""

from __future__ import annotations

import math
import time
import warnings

import numpy as np


def scenes():
    """(name, model) of the warm-up scenes."""
    import engine as e
    from engine.humanoid import add_humanoid

    out = []
    b = e.SceneBuilder()
    b.add_ground()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        add_humanoid(b)
    out.append(("humanoid", b.build()))
    for integrator in ("symplectic", "euler", "rk4"):
        b = e.SceneBuilder(integrator=integrator)
        b.add_ground()
        b.add_body("ball", e.Sphere(0.1), mass=1.0, position=(0, 0, 0.3), material="rubber")
        b.add_body("rod", e.Capsule(0.05, 0.2), mass=2.0, position=(0.5, 0, 0.3))
        b.add_body("box", e.Box((0.1, 0.1, 0.1)), mass=1.0, position=(1.0, 0, 0.3))
        b.add_body("top", e.Box((0.1, 0.1, 0.1)), mass=1.0, position=(1.0, 0, 0.55))
        b.add_spring("s", "ball", None, anchor_b=(0, 0, 1.0), stiffness=50.0)
        b.add_hinge("pivot", None, "rod", anchor=(0.5, 0, 0.55), axis=(0, 1, 0), limits=(-1.0, 1.0),
                    max_torque=5.0)
        out.append((f"shapes_{integrator}", b.build()))
    for name, settings in (("gauss_seidel", {"joint_solver": "gauss_seidel"}), ("thesis", {"solver": "thesis"})):
        b = e.SceneBuilder(**settings)
        b.add_ground()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            add_humanoid(b, position=(0, 0, 0.05))
        _breakable_chain(b, e, (2.0, 0, 0))
        b.add_body("crate", e.Box((0.1, 0.1, 0.1)), mass=1.0, position=(-1.0, 0, 0.095))
        b.add_body("lid", e.Box((0.1, 0.1, 0.1)), mass=1.0, position=(-1.0, 0, 0.29))
        out.append((name, b.build()))
    # Bodies landing on rubber within the first steps (free impacts, jointed
    # bounces), a box and a humanoid's feet deep in the ground (the static
    # contact projection and its rounds), greedy colouring.
    b = e.SceneBuilder(contact_coloring="greedy")
    b.add_ground(material="rubber")
    b.add_body("ball", e.Sphere(0.1), mass=1.0, position=(0, 2, 0.12), velocity=(0, 0, -3.0), material="rubber")
    b.add_body("deep", e.Box((0.2, 0.15, 0.1)), mass=2.0, position=(1.0, 2, -0.05), material="rubber")
    b.add_body("bob", e.Box((0.05, 0.05, 0.05)), mass=1.0, position=(2.0, 2, 0.06), velocity=(0, 0, -3.0),
               material="rubber")
    b.add_hinge("swing", None, "bob", anchor=(2.0, 2, 1.0), axis=(0, 1, 0))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        add_humanoid(b, position=(0, 0, -0.06))
    out.append(("bounce_and_projection", b.build()))
    # A chain pinned at both ends (a loop through the world, solved with the
    # tree: the coupled solve and the projection's loop path), lying on the ground.
    b = e.SceneBuilder()
    b.add_ground()
    prev = None
    for i in range(4):
        b.add_body(f"link{i}", e.Capsule(0.03, 0.07), mass=1.0, position=(0.2 * i + 0.1, -2.0, 0.031),
                   orientation=(math.cos(math.pi / 4), 0.0, math.sin(math.pi / 4), 0.0))
        b.add_ball(f"j{i}", prev, f"link{i}", anchor=(0.2 * i, -2.0, 0.031))
        prev = f"link{i}"
    b.add_ball("j4", prev, None, anchor=(0.8, -2.0, 0.031))
    out.append(("chain_loop", b.build()))
    b = e.SceneBuilder(gravity=None)
    b.enable("gravitation", G=1.0)
    b.add_body("sun", e.Sphere(0.1), mass=10.0, position=(0, 0, 0))
    b.add_body("planet", e.Sphere(0.01), mass=0.01, position=(1, 0, 0), velocity=(0, 3, 0))
    out.append(("gravitation", b.build()))
    return out


def _breakable_chain(b, e, at):
    """A chain hanging from the world: a hinge with limits, a ball with
    swing and twist limits, a fixed joint, each breakable."""
    x, y = at[0], at[1]
    b.add_body("link0", e.Capsule(0.03, 0.1), mass=1.0, position=(x, y, 1.0))
    b.add_body("link1", e.Capsule(0.03, 0.1), mass=1.0, position=(x, y, 0.74))
    b.add_body("link2", e.Box((0.05, 0.05, 0.05)), mass=1.0, position=(x, y, 0.56))
    b.add_hinge("top", None, "link0", anchor=(x, y, 1.13), axis=(0, 1, 0), limits=(-0.5, 0.5), break_force=1e4)
    b.add_ball("mid", "link0", "link1", anchor=(x, y, 0.87), swing_limits=(0.5, 0.5), twist_limits=(-0.3, 0.3),
               break_torque=1e3)
    b.add_fixed("end", "link1", "link2", anchor=(x, y, 0.61), break_force=5.0)


def warm_projection():
    """Compile the merge of two rounds of the static contact projection
    (``engine.contact_projection.merged``), which a step reaches only when a
    second round moves a body again."""
    from engine.contact_projection import ProjectedPoints, merged

    def points(worlds, bodies):
        worlds, bodies = np.asarray(worlds, dtype=np.int64), np.asarray(bodies, dtype=np.int64)
        return ProjectedPoints(worlds, bodies, np.zeros((worlds.size, 3)), np.zeros((worlds.size, 3)),
                               np.unique(worlds), np.zeros((2, 3, 3)), np.zeros((2, 3, 4)))

    merged(points([0, 0, 1], [1, 2, 1]), points([0, 1], [1, 2]))


def warm_collision():
    """Compile the kernels behind the numpy-facing collision functions
    (``engine.collision``: ``collide_rows``, ``aabb``, ``overlapping``), which
    a step reaches only when a body ends it deep in a static shape (the
    static contact projection), for every pair kind."""
    from engine.collision import aabb, collide_rows, overlapping
    from engine.core.collide import KIND_CODES

    kinds = np.array(sorted(KIND_CODES.values()))
    n = kinds.size
    quat = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
    collide_rows(kinds, np.zeros((n, 3)), quat, np.full((n, 3), 0.1), np.full((n, 3), 0.05), quat,
                 np.full((n, 3), 0.1), np.inf)
    types = np.arange(5)  # sphere, capsule, box, plane, none
    lo, hi = aabb(types, np.full((5, 3), 0.1), np.zeros((1, 5, 3)), np.tile([1.0, 0.0, 0.0, 0.0], (1, 5, 1)))
    overlapping(lo, hi, np.array([3, 0]), np.array([0, 1]), 0.01)


def warm(verbose: bool = False) -> float:
    """Step every warm-up scene for one world and a batch; returns seconds."""
    import engine as e

    t0 = time.perf_counter()
    for name, model in scenes():
        for worlds in (1, 16):
            state = model.initial_state(worlds)
            control = None
            if model.num_actuators:
                rng = np.random.default_rng(0)
                control = e.Control(motor=rng.uniform(-1, 1, (worlds, model.num_actuators)) * 10.0)
            for _ in range(3):
                e.step(model, state, control)
        if verbose:
            print(f"warmed {name} in {time.perf_counter() - t0:.1f} s", flush=True)
    warm_collision()
    warm_projection()
    if verbose:
        print(f"warmed the collision functions and the projection's merge in {time.perf_counter() - t0:.1f} s",
              flush=True)
    return time.perf_counter() - t0


def main():
    seconds = warm(verbose=True)
    print(f"kernels compiled and cached in {seconds:.1f} s")


if __name__ == "__main__":
    main()
