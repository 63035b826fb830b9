"""The tree solve's limit rows (``Settings.joint_limits_in_tree``): the active
set, solved through one factorisation per set of positions, ends on the
solution of the linear complementarity problem of the rigid equality and
limit rows."""

import math

import numpy as np
import pytest

import engine as e
import engine.joint_tree
from benchmarks.throughput import random_controls
from engine.humanoid import add_humanoid
from engine.joint_tree import _TreeSolver
from engine.math3d import mat_vec

#: Rigid joints with their limits in the tree, enough active-set passes to converge.
RIGID_LIMITS = {"joint_hertz": math.inf, "joint_limits_in_tree": True, "joint_active_set_passes": 30}


def _limit_rows_before(tree, js, state, h, use_bias):
    """The limit rows ``solve`` builds from ``state`` (on a copy, as building
    them takes the warm-started limit impulse off the velocities): rows
    (W, nj, 3, 3), σ and which exist, and each row's bias term σ·b."""
    before = state.copy()
    rows, r, sigma, exists, _ = tree.limit_rows(js, before, h, use_bias)
    w = before.angular_velocity
    bias = r - mat_vec(rows, w[:, js.child[tree.joints]] - w[:, js.parent[tree.joints]])
    return rows, sigma, exists, bias


@pytest.mark.parametrize("schur", [True, False], ids=["one factorisation", "refactored each pass"])
def test_limit_rows_end_each_tree_solve_complementary(monkeypatch, schur):
    """Both active-set solves (``SCHUR_LIMIT_ROWS``): a humanoid in the air
    under random maximum torques (its limbs hit their limits every few
    steps): after each tree solve the equality rows hold
    (J u + b = 0), every limit row is at or past its bound's speed
    (σ (J u + b) >= 0), the limit impulses push (σ λ >= 0, stored as
    λ_lo, λ_hi, λ_swing >= 0), and a row with an impulse is held exactly."""
    b = e.SceneBuilder(**RIGID_LIMITS)
    add_humanoid(b)
    model = b.build()
    W = 4
    state = model.initial_state(W)
    controls = random_controls(model, W, seed=3)
    solve = _TreeSolver.solve
    worst = {"equality": 0.0, "closing": 0.0, "held": 0.0, "pulling": 0.0}
    counts = {"solves": 0, "held rows": 0}

    def checked(tree, js, model_, state_, bias_rate, mass_scale, impulse_scale, use_bias, h):
        rows, sigma, exists, bias = _limit_rows_before(tree, js, state_, h, use_bias)
        solve(tree, js, model_, state_, bias_rate, mass_scale, impulse_scale, use_bias, h)
        *_, mask, r_eq = tree.jacobians(js, state_, use_bias, bias_rate)
        w = state_.angular_velocity
        v = mat_vec(rows, w[:, js.child[tree.joints]] - w[:, js.parent[tree.joints]]) + bias
        lam = state_.joint_limit_impulse[:, tree.joints]
        lam_rows = np.stack((lam[..., 0] + lam[..., 1], lam[..., 2], np.zeros(lam.shape[:2])), axis=-1)
        held = exists & (lam_rows > 0)
        worst["equality"] = max(worst["equality"], float(np.abs(r_eq * mask).max()))
        worst["closing"] = max(worst["closing"], float(np.where(exists, -sigma * v, 0.0).max()))
        worst["held"] = max(worst["held"], float(np.where(held, np.abs(v), 0.0).max()))
        worst["pulling"] = max(worst["pulling"], float(-lam.min()))
        counts["solves"] += 1
        counts["held rows"] += int(held.sum())

    monkeypatch.setattr(_TreeSolver, "solve", checked)
    if not schur:
        monkeypatch.setattr(engine.joint_tree, "SCHUR_LIMIT_ROWS", -1)
    for k in range(120):
        e.step(model, state, controls[k % len(controls)])
    assert counts["held rows"] > 100, counts  # the limits did act
    assert worst["equality"] < 1e-8, worst  # m/s, rad/s
    assert worst["closing"] < 1e-5, worst  # rad/s (the active set adds rows closing faster than 1e-6)
    assert worst["held"] < 1e-8, worst
    assert worst["pulling"] <= 0.0, worst
