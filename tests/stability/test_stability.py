"""Hard cases stay numerically stable (the scenes of benchmarks/scenes.py).

Every case asserts, over its run:

* no NaN/inf (the engine raises SimulationError; run_case records it);
* energy never rises above its start plus the motors' work by more than the
  case's stated tolerance (``Case.energy_tol``: 1 % of the start's |E| in the
  scene's own frame, at least 0.5 J, unless the case states otherwise);
* joint anchor error below ``Case.anchor_bound`` (1 cm; 5 cm for the 100 m/s
  impact) and penetration below ``Case.penetration_bound`` (2 cm for boxes,
  5 cm for ragdolls, 2 mm for the 1 cm bodies, 10 cm for the 10 m ones) from
  ``Case.penetration_after`` on;
* scenes that should come to rest do: every body's speed below
  ``Case.rest_speed`` from ``Case.rest_time`` on (when the run reaches it);
* overlap and coincident-centre scenes never fling a body: no body moves
  faster than ``speed_bound`` beyond what its fall from its highest point so
  far explains (``Result.max_fling_speed``).

The fast part runs shortened durations (and, where a full scene costs more
than about 5 s, a smaller scene of the same kind: stack of 8, pyramid of 4
rows, pile of 3 ragdolls, the 10-box 2D overlap pyramid); the full scenes and durations
are marked slow. Bounds are the same in both; where the engine misses one the
test stays with the bound and is marked xfail(strict=True) with the measured
figure.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from benchmarks import scenes as sc

pytestmark = pytest.mark.stability


def check(case, result):
    """The list of bounds the run missed, each with the measured figure."""
    misses = []
    if result.nan:
        misses.append(f"NaN/inf: {result.error}")
        return misses
    if result.energy_rise > case.energy_tol:
        misses.append(f"energy rose {result.energy_rise:.4g} J above start + motor work "
                      f"(tolerance {case.energy_tol:.4g} J)")
    if case.anchor_bound is not None and result.max_anchor_error > case.anchor_bound:
        misses.append(f"anchor error {result.max_anchor_error:.4g} m > {case.anchor_bound:g} m")
    if case.penetration_bound is not None and result.max_penetration_after > case.penetration_bound:
        misses.append(f"penetration {result.max_penetration_after:.4g} m > {case.penetration_bound:g} m")
    if case.speed_bound is not None and result.max_fling_speed > case.speed_bound:
        misses.append(f"fling speed {result.max_fling_speed:.4g} m/s > {case.speed_bound:g} m/s "
                      f"(largest speed {result.max_speed_all:.4g} m/s)")
    if case.rest_time is not None and result.sim_time >= case.rest_time and not math.isnan(result.rest_speed_max):
        if result.rest_speed_max > case.rest_speed:
            misses.append(f"not at rest: speed {result.rest_speed_max:.4g} m/s after {case.rest_time:g} s "
                          f"(bound {case.rest_speed:g} m/s)")
    return misses


def run_and_check(case, seconds=None, quick=True, known_miss=None, missed_bounds=None):
    """Run ``case`` and assert its bounds. Staying finite is asserted always; a
    case with a ``known_miss`` (the measured figures it misses by) is an
    expected failure for its other bounds, and fails when it meets them all, so
    the table of known misses cannot go stale. ``missed_bounds``: if given,
    only misses starting with one of these (e.g. "anchor error") are
    expected; any other miss fails."""
    steps = None if seconds is None else int(round(seconds / case.dt))
    result = sc.run_case(case, steps=steps, quick=quick)
    assert not result.nan, f"{case.name}: NaN/inf: {result.error}"
    misses = check(case, result)
    if missed_bounds is not None:
        unexpected = [m for m in misses if not m.startswith(tuple(missed_bounds))]
        assert not unexpected, f"{case.name}: " + "; ".join(unexpected)
    if known_miss is not None:
        if not misses:
            pytest.fail(f"{case.name} now meets every bound: remove it from the known misses ({known_miss})")
        pytest.xfail(f"{known_miss}; this run: " + "; ".join(misses))
    assert not misses, f"{case.name}: " + "; ".join(misses)
    return result


FAR = sc.FAR_OFFSET

# name -> (case factory, simulated seconds) of the fast part
FAST = {
    "mass_ratio_stack": (lambda: sc.mass_ratio_stack(), 2.0),
    "mass_ratio_sandwich": (lambda: sc.mass_ratio_sandwich(), 2.0),
    "ball_and_chain": (lambda: sc.ball_and_chain(), 3.0),
    "stack_5": (lambda: sc.box_stack(n=5), 2.5),
    "pyramid_3": (lambda: sc.pyramid(rows=3), 2.0),
    "overlap_recovery_2d": (lambda: sc.overlap_recovery(depth=1), 3.0),
    "ragdoll_pile_2": (lambda: sc.ragdoll_pile(count=2), 1.0),
    "sphere_grid": (lambda: sc.sphere_grid(), 1.0),
    "chain_loop": (lambda: sc.chain_loop(), 3.0),
    "ragdoll_impact_100": (lambda: sc.ragdoll_impact(), 0.5),
    "large_dt_ragdoll": (lambda: sc.large_dt_ragdoll(), 2.0),
    "large_dt_stack": (lambda: sc.large_dt_stack(n=6), 3.0),
    "tiny_bodies": (lambda: sc.tiny_bodies(), 1.6),
    "huge_bodies": (lambda: sc.huge_bodies(), 4.0),
    "stiff_spring": (lambda: sc.stiff_spring(), 2.0),
    "degenerate_capsules": (lambda: sc.degenerate_capsules(), 2.5),
    "degenerate_edges": (lambda: sc.degenerate_edges(), 2.5),
    "degenerate_coincident": (lambda: sc.degenerate_coincident(), 3.0),
    "mass_ratio_stack_far": (lambda: sc.mass_ratio_stack(FAR), 2.0),
    "mass_ratio_sandwich_far": (lambda: sc.mass_ratio_sandwich(FAR), 2.0),
    "ball_and_chain_far": (lambda: sc.ball_and_chain(FAR), 2.0),
    "overlap_recovery_2d_far": (lambda: sc.overlap_recovery(FAR, depth=1), 3.0),
    "ragdoll_impact_100_far": (lambda: sc.ragdoll_impact(FAR), 0.5),
    "degenerate_capsules_far": (lambda: sc.degenerate_capsules(FAR), 2.5),
    "degenerate_edges_far": (lambda: sc.degenerate_edges(FAR), 2.5),
    "degenerate_coincident_far": (lambda: sc.degenerate_coincident(FAR), 3.0),
}

#: measured misses of the fast part (python -m pytest tests/stability, this checkout); the
#: 1/30 s drop's 3.5 cm landing (bound 3) is met since the static contact projection
FAST_XFAIL = {}

#: measured misses of the full scenes (``python -m benchmarks.stability --case NAME``; every
#: bound is a maximum over the run, the rest bound over [rest_time, end], so a miss of the
#: quick duration is a miss of the full duration too, but not the other way round:
#: stack_20_small's 3 s quick run stays at 0.044 m/s).
SLOW_XFAIL = {
    "stack_20_small": "the column of 20 cm boxes topples: fastest box 0.96 m/s at 5 s (bound 0.05 from 2 s; "
                      "8 substeps topple it too, 0.5 m boxes rest)",
    "sphere_grid": "anchor error 1.27 cm (bound 1 cm) when the net's free edge whips through at 1.9 s; "
                   "missed since 3a8babc (README, hard cases)",
    "sphere_grid_far": "anchor error 1.56 cm 10 km out (bound 1 cm), as sphere_grid",
}


@pytest.mark.parametrize("name", list(FAST))
def test_hard_case_fast(name):
    factory, seconds = FAST[name]
    run_and_check(factory(), seconds, known_miss=FAST_XFAIL.get(name))


@pytest.mark.slow
@pytest.mark.parametrize("name", [n for n in sc.case_names()
                                  if not n.startswith(("ragdoll_max_torque", "ragdoll_drops"))])
def test_hard_case_full(name):
    """The full scenes for their full durations (as ``python -m benchmarks.stability``)."""
    run_and_check(sc.make_case(name), quick=False, known_miss=SLOW_XFAIL.get(name))


# ------------------------------------------------------------------ dropped ragdolls
def test_ragdoll_drops_land_and_come_to_rest():
    """Six drops from 0.5-1.5 m, upright and tilted, one per world, for the
    case's full 7 s: finite, no energy gain, joints within 1 cm, penetration
    under 5 cm and every speed under 2 cm/s from 5 s on. Measured: 0.2 mm,
    2.0 cm deep, 0.007 cm/s from 5 s. At ``SOFT_JOINTS`` (the defaults
    before 2026-12-04) the joints opened by 4.0 cm (the post-stabilisation's
    slop there), 3.2 cm deep."""
    run_and_check(sc.ragdoll_drops())


def test_random_ragdoll_drops_come_to_rest():
    """Eight drops drawn at random (``ragdoll_drops_random``, seed 2), for
    7 s: the same bounds. Measured: 0.2 mm, 2.5 cm deep, 0.047 cm/s from
    5 s. At ``SOFT_JOINTS`` the joints opened by 7.1 cm at one landing step
    (elsewhere 4.0 cm, the slop), 3.5 cm deep."""
    run_and_check(sc.ragdoll_drops_random())


def test_rigid_limits_leave_a_random_drop_twitching():
    """The same eight drops with soft joints and Gauss-Seidel limit rows
    (``SOFT_JOINTS``) and ``limit_soft_margin=0`` (limits rigid in contact
    too): an arm keeps trembling against its shoulder limit, not at rest from
    5 s (measured 5.5 cm/s). The margin is what rests them there; the
    defaults' limits in the tree solve rest without it (0.05 cm/s)."""
    case = sc.ragdoll_drops_random()
    case.model = case.model.with_settings(**sc.e.SOFT_JOINTS, limit_soft_margin=0.0)
    result = sc.run_case(case)
    assert not result.nan
    assert result.rest_speed_max > case.rest_speed


# ------------------------------------------------------------------ random maximum torques
def test_max_torque_fast():
    """8 worlds of the standing ragdoll, every joint at ± its maximum torque,
    90 steps: no NaN, energy within start + motor work, joints within 1 cm,
    no limb deeper than 5 cm. Until the static contact projection was on by
    default (2 cm, ``engine.contact_projection``) limbs went 9.9 cm deep
    here: 14 of 32 worlds (seeds 0 and 1, 16 worlds each) went deeper than
    5 cm within these 90 steps. The energy bound holds since the motors'
    work is each step's torque times its joint's turn
    (``benchmarks.scenes._motor_work``): with a trapezoid rule on the power at
    the step's ends one of these worlds gained 11 J more than the work
    counted in its first step. At ``SOFT_JOINTS`` also joints 4.0 cm (the
    post-stabilisation's slop; 6.6 cm without)."""
    case = sc.ragdoll_max_torque(num_worlds=8)
    run_and_check(case, 90 * case.dt)


@pytest.mark.slow
def test_max_torque_quick_length():
    """The benchmark's quick length: 2,000 steps."""
    case = sc.ragdoll_max_torque()
    run_and_check(case, 2_000 * case.dt)


@pytest.mark.slow
def test_max_torque_100k_steps():
    """The long run: 100,000 steps of random maximum torques."""
    case = sc.ragdoll_max_torque()
    run_and_check(case, 100_000 * case.dt)


@pytest.mark.slow
def test_max_torque_far():
    case = sc.ragdoll_max_torque(FAR)
    run_and_check(case, 2_000 * case.dt)


# ------------------------------------------------------------------ determinism
def _replay(steps, seed, num_worlds=2):
    case = sc.ragdoll_max_torque(num_worlds=num_worlds, seed=seed)
    state = case.state.copy()
    for k in range(steps):
        sc.e.step(case.model, state, case.controller(k, state))
    return state


def test_replay_is_bit_identical():
    """The same seed and actions give a bit-identical state (and another seed does not)."""
    a = _replay(16, seed=7)
    b = _replay(16, seed=7)
    assert a.equal(b)
    c = _replay(16, seed=8)
    assert not np.array_equal(a.position, c.position)


# ------------------------------------------------------------------ the fling measure
def _one_body_case(position, velocity):
    b = sc._builder(np.zeros(3))
    b.add_body("box", sc.e.Box((0.25, 0.25, 0.25)), mass=1.0, position=position, velocity=velocity)
    return sc._make("one_box", "one box", b, np.zeros(3), duration=1.0, quick_duration=1.0)


def test_fling_speed_discounts_a_fall_but_not_a_launch():
    """A box dropped 1.75 m reaches √(2 g h) = 5.9 m/s with no fling speed; one
    thrown sideways at 2.5 m/s from 5 m up keeps a fling speed of 2.5 m/s
    while its speed grows with the fall."""
    dropped = sc.run_case(_one_body_case((0, 0, 2.0), (0, 0, 0)), steps=60)
    assert dropped.max_speed_all == pytest.approx(math.sqrt(2 * 9.81 * 1.75), rel=0.03)
    assert dropped.max_fling_speed < 0.05
    thrown = sc.run_case(_one_body_case((0, 0, 5.0), (2.5, 0, 0)), steps=45)
    assert thrown.max_speed_all > 6.0
    assert thrown.max_fling_speed == pytest.approx(2.5, abs=0.02)
