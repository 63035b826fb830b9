"""Soak: 1,000 worlds x 1,000 steps of the standing ragdoll under random maximum
torques (every actuated axis at ± its maximum, signs redrawn every 4 steps).

Asserts no world turns non-finite and the joint anchor error stays under 1 cm
throughout; then replays a few worlds alone from the same seed and recorded
actions and asserts the result is bit-identical to the batched run.
A short version (4 worlds x 30 steps) runs in the fast suite. The bounds and the
replay are separate tests so that a missed bound does not hide the replay.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest

import engine as e
from benchmarks import scenes as sc

pytestmark = pytest.mark.stability

ANCHOR_BOUND = 0.01  # m
REPLAY_WORLDS = (0, 2, 499, 998)


def soak(num_worlds, steps, seed=0):
    case = sc.ragdoll_max_torque(num_worlds=num_worlds, seed=seed)
    model = case.model.with_settings(check_finite=False)
    state = model.initial_state(num_worlds)
    ctrl = sc.RandomMaxTorque(model, num_worlds, seed=seed)
    replay = [w for w in REPLAY_WORLDS if w < num_worlds]
    actions = []
    worst_anchor = 0.0
    worst_at = None
    nan_worlds = set()
    for k in range(steps):
        control = ctrl(k, state)
        actions.append(control.motor[replay].copy())
        e.step(model, state, control)
        bad = state.nonfinite_worlds()
        nan_worlds.update(int(w) for w in bad)
        err = model.joints.anchor_error(state)
        err = np.where(np.isfinite(err), err, 0.0)
        m = float(err.max())
        if m > worst_anchor:
            worst_anchor, worst_at = m, (k, int(np.argmax(err.max(axis=1))))
    return model, state, replay, actions, worst_anchor, worst_at, sorted(nan_worlds)


def replay_alone(model, replay, actions):
    alone = model.initial_state(len(replay))
    for u in actions:
        e.step(model, alone, e.Control(motor=u))
    return alone


@functools.lru_cache(maxsize=2)
def soak_cached(num_worlds, steps):
    return soak(num_worlds, steps)


def check_bounds(num_worlds, steps):
    model, state, replay, actions, worst, at, nan_worlds = soak_cached(num_worlds, steps)
    assert not nan_worlds, f"{len(nan_worlds)} worlds turned non-finite: {nan_worlds[:10]}"
    assert worst < ANCHOR_BOUND, f"anchor error {worst:.4g} m at (step, world) {at}"


def check_replay(num_worlds, steps):
    model, state, replay, actions, *_ = soak_cached(num_worlds, steps)
    alone = replay_alone(model, replay, actions)
    assert alone.equal(state.select(replay)), "replaying worlds alone is not bit-identical to the batch"


def test_soak_short_replay_bit_identical():
    check_replay(4, 30)


def test_soak_short():
    # At SOFT_JOINTS (the defaults before 2026-12-04) a known miss: 4.0 cm at step 23 (world 2), the
    # post-stabilisation's slop.
    check_bounds(4, 30)


#: The two 1,000-world tests share one soak (``soak_cached``) when they run in one
#: process: with ``-n 2 --dist loadgroup`` (README) this group keeps them on one
#: worker, so the 10-minute soak runs once instead of once per worker.
SOAK_GROUP = pytest.mark.xdist_group("soak_1000_worlds")


@pytest.mark.slow
@SOAK_GROUP
def test_soak_replay_bit_identical():
    check_replay(1000, 1000)


@pytest.mark.slow
@SOAK_GROUP
def test_soak_1000_worlds_1000_steps():
    # At SOFT_JOINTS (the defaults before 2026-12-04) a known miss: 4.0 cm at step 8 (world 957), the
    # post-stabilisation's slop; no NaN.
    check_bounds(1000, 1000)
