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
    under random maximum torques. At each step's start a copy of the state,
    its spins kicked at random so that limits close and open, gets the tree
    solve the substeps run (``engine.core.tree_solve.solve_world``), biased
    and then relaxed. After each solve the equality rows hold (J u + b = 0),
    every limit row is at or past its bound's speed (σ (J u + b) >= 0), the
    limit impulses push (σ λ >= 0, stored as λ_lo, λ_hi, λ_swing >= 0), and
    a row with an impulse is held exactly."""
    b = e.SceneBuilder(**RIGID_LIMITS)
    add_humanoid(b)
    model = b.build()
    W = 4
    state = model.initial_state(W)
    controls = random_controls(model, W, seed=3)
    js, tree = model.joints, model.joints.tree
    h = model.settings.dt / model.settings.substeps
    worst = {"equality": 0.0, "closing": 0.0, "held": 0.0, "pulling": 0.0}
    counts = {"solves": 0, "held rows": 0}

    def checked_solve(copy, use_bias):
        bias_rate, mass_scale, impulse_scale = js._soft_terms(use_bias, js._tree_soft)
        rows, sigma, exists, bias = _limit_rows_before(tree, js, copy, h, use_bias)
        tree.solve(js, model, copy, bias_rate, mass_scale, impulse_scale, use_bias, h)
        *_, mask, r_eq = tree.jacobians(js, copy, use_bias, bias_rate)
        w = copy.angular_velocity
        v = mat_vec(rows, w[:, js.child[tree.joints]] - w[:, js.parent[tree.joints]]) + bias
        lam = copy.joint_limit_impulse[:, tree.joints]
        lam_rows = np.stack((lam[..., 0] + lam[..., 1], lam[..., 2], np.zeros(lam.shape[:2])), axis=-1)
        held = exists & (lam_rows > 0)
        worst["equality"] = max(worst["equality"], float(np.abs(r_eq * mask).max()))
        worst["closing"] = max(worst["closing"], float(np.where(exists, -sigma * v, 0.0).max()))
        worst["held"] = max(worst["held"], float(np.where(held, np.abs(v), 0.0).max()))
        worst["pulling"] = max(worst["pulling"], float(-lam.min()))
        counts["solves"] += 1
        counts["held rows"] += int(held.sum())

    if not schur:
        monkeypatch.setattr(engine.joint_tree, "SCHUR_LIMIT_ROWS", -1)
    rng = np.random.default_rng(5)
    for k in range(120):
        u = controls[k % len(controls)]
        copy = state.copy()
        js.begin_step(model, copy, h)
        # Kicks of the bodies' spins (normal, 2 rad/s) drive joints into and out of their limits.
        copy.angular_velocity[...] += rng.normal(0.0, 2.0, copy.angular_velocity.shape)
        checked_solve(copy, True)
        checked_solve(copy, False)
        e.step(model, state, u)
    assert counts["solves"] == 240
    assert counts["held rows"] > 100, counts  # the limits did act
    assert worst["equality"] < 1e-8, worst  # m/s, rad/s
    assert worst["closing"] < 1e-5, worst  # rad/s (the active set adds rows closing faster than 1e-6)
    assert worst["held"] < 1e-8, worst
    assert worst["pulling"] <= 0.0, worst


def _humanoid_at_random_positions(W, seed):
    """A humanoid (ground, motors) with W worlds of random body positions
    (±0.3 m) and orientations, its joint set begun for a substep: the tree's
    metric M at those orientations and the Jacobian blocks of those frames."""
    b = e.SceneBuilder()
    b.add_ground()
    add_humanoid(b)
    model = b.build()
    state = model.initial_state(W)
    rng = np.random.default_rng(seed)
    state.position[...] += rng.uniform(-0.3, 0.3, state.position.shape)
    q = rng.normal(size=state.orientation.shape)
    state.orientation[...] = q / np.linalg.norm(q, axis=-1, keepdims=True)
    js = model.joints
    js.begin_step(model, state, model.settings.dt)
    return model, state, js, js.tree


def _dense_system(model, js, tree, Ja, Jb, mask, w):
    """K = J M⁻¹ Jᵀ of world w over its used rows (dense), and which of the 6 nj rows those are."""
    nj, N = tree.joints.size, model.num_bodies
    J = np.zeros((6 * nj, 6 * N))
    for k, (a, b) in enumerate(zip(js.parent[tree.joints], js.child[tree.joints])):
        for body, block in ((a, Ja), (b, Jb)):
            if model.dynamic[body]:
                J[6 * k:6 * k + 6, 6 * body:6 * body + 6] += block[w, k]
    M_inv = np.zeros((6 * N, 6 * N))
    for k, body in enumerate(tree.t.bodies):
        M_inv[6 * body:6 * body + 6, 6 * body:6 * body + 6] = np.linalg.inv(tree.M[w, k])
    used = mask[w].reshape(-1) > 0
    return (J @ M_inv @ J.T)[np.ix_(used, used)], used


@pytest.mark.parametrize("ball_rows, leaf_inverse", [(True, True), (False, True), (True, False)],
                         ids=["closed forms", "no ball closed form", "no leaf closed form"])
def test_tree_kernels_solve_the_joint_system_to_rounding(ball_rows, leaf_inverse):
    """The factorisation and substitution kernels (engine.core.tree) solve
    (J M⁻¹ Jᵀ) X = R on the humanoid's tree at random positions, for several
    right-hand sides at once: the residual is rounding, each row's within a
    few thousand ulps of |K| |x| + |r| (the tree's pivots carry the system's
    condition), and the unused rows (ball joints' angular rows) solve to 0."""
    W = 3
    model, state, js, tree = _humanoid_at_random_positions(W, seed=5)
    *_, Ja, Jb, mask = tree.blocks(js, state, tree)
    rng = np.random.default_rng(6)
    R = rng.normal(size=mask.shape + (4,)) * mask[..., None]
    factors = tree._factor(Ja, Jb, mask, tree.M, ball_rows, tree.M_inv if leaf_inverse else None)
    X = tree._substitute_columns(factors, R)
    assert np.isfinite(X).all()
    assert (X[mask == 0] == 0).all()
    for w in range(W):
        K, used = _dense_system(model, js, tree, Ja, Jb, mask, w)
        x, r = X[w].reshape(-1, 4)[used], R[w].reshape(-1, 4)[used]
        bound = 4096 * np.finfo(float).eps * (np.abs(K) @ np.abs(x) + np.abs(r))
        assert (np.abs(K @ x - r) <= bound).all(), w
        # One right-hand side alone: the same operations as its column among several.
        assert np.array_equal(tree._substitute(factors, R[..., 0])[w].reshape(-1)[used], x[:, 0])


def test_tree_kernels_give_each_world_the_bits_it_gets_alone():
    """W worlds factored and substituted together (the batched kernels' prange
    path from SERIAL_BELOW worlds) give each world the same D⁻¹, L and
    solutions, bit for bit, as factoring that world alone."""
    W = 12
    model, state, js, tree = _humanoid_at_random_positions(W, seed=7)
    *_, Ja, Jb, mask = tree.blocks(js, state, tree)
    R = np.random.default_rng(8).normal(size=mask.shape + (3,)) * mask[..., None]
    for ball_rows in (True, False):
        Dinv, L = tree._factor(Ja, Jb, mask, tree.M, ball_rows, tree.M_inv)
        X = tree._substitute_columns((Dinv, L), R)
        for w in range(W):
            one = slice(w, w + 1)
            Dinv1, L1 = tree._factor(Ja[one], Jb[one], mask[one], tree.M[one], ball_rows, tree.M_inv[one])
            assert np.array_equal(Dinv1[0], Dinv[w]) and np.array_equal(L1[0], L[w]), (ball_rows, w)
            assert np.array_equal(tree._substitute_columns((Dinv1, L1), R[one])[0], X[w]), (ball_rows, w)


def _limited_chain():
    """A pendulum of three links hanging from a static anchor: a hinge with a
    twist range, then two ball joints with swing cones and twist ranges (5
    limit rows), rigid, limits in the tree."""
    b = e.SceneBuilder(**RIGID_LIMITS)
    anchor = b.add_body("anchor", None, static=True, position=(0.0, 0.0, 2.0))
    links = [b.add_body(f"link{i}", e.Capsule(0.04, 0.2), mass=1.0 + i, position=(0.0, 0.0, 1.8 - 0.3 * i))
             for i in range(3)]
    b.add_hinge("hinge", anchor, links[0], anchor=(0.0, 0.0, 2.0), axis=(0.0, 1.0, 0.0), limits=(-0.3, 0.3))
    for i in (1, 2):
        b.add_ball(f"ball{i}", links[i - 1], links[i], anchor=(0.0, 0.0, 1.95 - 0.3 * i), twist_axis=(0.0, 0.0, 1.0),
                   swing_limits=(0.25, 0.4), twist_limits=(-0.2, 0.2))
    return b.build()


def test_both_active_set_paths_give_the_same_impulses(monkeypatch):
    """The active set on one factorisation of the equality rows, the active
    limit rows added by their Schur complement, and the active set that
    factors the system of its active rows each pass: the same velocities and
    limit impulses to rounding (1e-9 of 1 + |value|: the KKT system's
    condition amplifies it), on a chain with fewer limit rows (5) than a
    right-hand side has entries, its spins kicked so that limits close and
    open (both solves of each kick, biased and relaxed)."""
    model = _limited_chain()
    js, tree = model.joints, model.joints.tree
    rows = tree.limit_candidates[0].size
    assert rows == 5
    h = model.settings.dt / model.settings.substeps
    W = 8
    state = model.initial_state(W)
    rng = np.random.default_rng(11)
    worst, held = 0.0, 0
    for k in range(40):
        state.angular_velocity[...] += rng.normal(0.0, 3.0, state.angular_velocity.shape)
        results = []
        for threshold in (rows, -1):
            monkeypatch.setattr(engine.joint_tree, "SCHUR_LIMIT_ROWS", threshold)
            copy = state.copy()
            js.begin_step(model, copy, h)
            assert tree.uses_schur() == (threshold == rows)
            for use_bias in (True, False):
                soft = js._soft_terms(use_bias, js._tree_soft)
                tree.solve(js, model, copy, *soft, use_bias, h)
            results.append((copy.velocity.copy(), copy.angular_velocity.copy(), copy.joint_limit_impulse.copy()))
        (v1, w1, l1), (v2, w2, l2) = results
        for x, y in ((v1, v2), (w1, w2), (l1, l2)):
            worst = max(worst, float((np.abs(x - y) / (1.0 + np.abs(y))).max()))
        held += int((l1 > 0).sum())
        e.step(model, state)
    assert held > 50, held  # the limits did act
    assert worst < 1e-9, worst  # relative to 1 + |value| (m/s, rad/s, N m s)
