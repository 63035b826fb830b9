"""Contacts of articulations on static bodies solved with the articulation's
response (``Settings.articulated_contacts``, ``engine.articulated_contacts``)."""

import math

import numpy as np

import engine as e
from benchmarks import scenarios, scenes
from engine.articulated_contacts import ArticulatedContacts
from engine.core import articulated as kernels

#: Rigid joints, limits in the tree and a 0.2 mm post-stabilisation slop at the
#: default 4 substeps: the joints of ACCURATE without its 16 substeps.
RIGID = dict(joint_hertz=math.inf, joint_limits_in_tree=True, joint_projection_slop=2e-4)


def _drop(world, seconds, case=None, **settings):
    """World ``world`` of ``case`` (default benchmarks.scenes.ragdoll_drops)
    alone, stepped for ``seconds``: (model, state, max anchor error m, max
    penetration m, max body speed m/s over the last 0.5 s)."""
    case = case or scenes.ragdoll_drops()
    model = case.model.with_settings(**settings)
    state = model.initial_state(1)
    for key in ("position", "orientation", "velocity", "angular_velocity"):
        state.arrays[key][0] = case.state.arrays[key][world]
    steps = int(round(seconds / model.settings.dt))
    anchor = pen = late = 0.0
    for k in range(steps):
        e.step(model, state)
        anchor = max(anchor, float(model.joints.anchor_error(state).max()))
        pen = max(pen, float(scenarios.ground_penetration(model, state)[0]))
        if k >= steps - 30:
            late = max(late, float(np.linalg.norm(state.velocity, axis=-1).max()))
    return model, state, anchor, pen, late


def _prepared(model, state):
    """The contact rows, joint set and ArticulatedContacts of the next step, prepared as ``step`` does."""
    h = model.settings.dt / model.settings.substeps
    contacts, joints = model.contacts, model.joints
    contacts.begin_step(model, state, h)
    joints.begin_step(model, state, h, contacts.bodies_in_contact(state))
    return contacts.rows, joints, ArticulatedContacts(model, state, contacts.rows, joints)


def test_response_keeps_every_joint_and_gives_a_delassus_matrix():
    """Z, the response to a unit impulse on each contact column, moves the
    bodies without any joint-row velocity (J_t Z = 0 to rounding); A = J_c Z
    is symmetric positive semi-definite, and each point's articulated
    effective mass 1/A_ii is at least its one body's (the joints only add
    the bodies behind it)."""
    model, state, *_ = _drop(1, 0.5, articulated_contacts=True, **RIGID)
    rows, joints, art = _prepared(model, state)
    assert not art.empty and art.rows.size >= 2
    tree = joints.tree
    a, b, _, _, _, _, _, Ja, Jb, mask = tree.blocks(joints, state, tree)
    S = art.arrays
    Z = art.response(0).transpose(1, 2, 0)[None]  # (1, N, 6, columns)
    joint_rows = (np.matmul(Ja, Z[:, a]) + np.matmul(Jb, Z[:, b])) * mask[..., None]
    assert np.abs(joint_rows).max() <= 1e-9 * np.abs(Z).max()
    A = art.delassus(0)
    assert np.abs(A - A.T).max() <= 1e-12 * np.abs(A).max()
    assert np.linalg.eigvalsh(0.5 * (A + A.T)).min() >= -1e-9 * np.abs(A).max()
    assert S.m.size == 3 * rows.valid[art.rows].sum()  # a normal and two friction columns per valid point
    single = rows.mn[S.pt_row, S.pt_slot]  # one body's normal effective masses of the valid points
    articulated = S.m[0::3]
    assert np.all(articulated >= single * (1 - 1e-9))
    assert np.any(articulated > 2.0 * single)  # a foot on the ground carries more than the foot


def test_rigid_ragdoll_lands_and_rests_with_its_joints_closed():
    """The 1 m upright drop with rigid joints at 4 substeps: with the
    articulation's response (``engine.CLOSED_JOINTS``: RIGID and
    articulated_contacts) the joints stay within 1 mm (the 0.2 mm slop),
    nothing sinks 5 cm, and over the last half second of 3 s nothing moves
    faster than 1 cm/s (measured with its two sweeps: 0.2 mm, 0.71 cm,
    0.02 mm/s; one sweep 2.7 cm and 6.9 mm/s, still settling). The same
    joints with the contacts solved body by body still chatter there
    (measured 0.47 m/s): a contact stops the foot alone and the joints hand
    the impulse back."""
    _, _, anchor, pen, late = _drop(1, 3.0, **e.CLOSED_JOINTS)
    assert anchor < 1e-3
    assert pen < 0.05
    assert late < 0.01
    _, _, _, _, late_gs = _drop(1, 3.0, articulated_contacts=False, **RIGID)
    assert late_gs > 0.05


def test_a_limb_resting_against_its_limit_comes_to_rest():
    """World 1 of ``ragdoll_drops_random`` (seed 2: 1.31 m, tilted -0.245 rad)
    at ``engine.CLOSED_JOINTS`` lands with a foot held at its ankle limit.
    With the joints solved before the articulated contacts, each contact
    solve pushed the foot into its limit and the next joint solve out again:
    it twitched at 0.080 m/s to the end of 7 s. With the joints last (their
    limits exact, the soft contacts taking up the rest) nothing moves faster
    than 2 cm/s over the last half second of 7 s (the hard cases' bound;
    measured under 0.1 mm/s, 0.006 m/s with one sweep), the joints within 1 mm."""
    _, _, anchor, _, late = _drop(1, 7.0, case=scenes.ragdoll_drops_random(), **e.CLOSED_JOINTS)
    assert anchor < 1e-3
    assert late < 0.02


def test_scenes_without_articulations_step_as_without_the_setting():
    """A box on the ground has no jointed rows: the setting changes no bit."""
    states = []
    for on in (False, True):
        model = scenarios.sliding_box().build().with_settings(articulated_contacts=on)
        state = model.initial_state(1)
        for _ in range(60):
            e.step(model, state)
        states.append(state)
    for key in ("position", "orientation", "velocity", "angular_velocity"):
        assert np.array_equal(states[0].arrays[key], states[1].arrays[key])


def test_batch_replays_bit_for_bit():
    """Two replays of one batch are identical, and a world stepped alone is
    the same world in the batch bit for bit, though its contact columns are
    packed among the other worlds' there (every sum of a world runs over its
    own columns, in an order of its own)."""
    case = scenes.ragdoll_drops()
    model = case.model.with_settings(articulated_contacts=True, **RIGID)
    runs = []
    for _ in range(2):
        state = case.state.copy()
        for _ in range(50):
            e.step(model, state)
        runs.append(state)
    assert np.array_equal(runs[0].position, runs[1].position)
    assert np.array_equal(runs[0].velocity, runs[1].velocity)
    alone = model.initial_state(1)
    for key in ("position", "orientation", "velocity", "angular_velocity"):
        alone.arrays[key][0] = case.state.arrays[key][2]
    for _ in range(50):
        e.step(model, alone)
    for key in ("position", "orientation", "velocity", "angular_velocity"):
        assert np.array_equal(alone.arrays[key][0], runs[0].arrays[key][2]), key


def _reference_sweep(A, u, lam, gain, bias, isc_lam, mu):
    """One projected Gauss-Seidel sweep written out plainly on one world's
    arrays (A (k, k), the rest (k,); gain, bias, isc_lam read at the normal
    columns 0, 3, ...): the normal columns, then the friction pairs in the
    Coulomb disc |λ_t| <= μ λ_n, u updated by every column's change (no
    column skipped). Returns u, lam, u_before (k / 3,)."""
    u, lam, start = u + 0.0, lam.copy(), lam.copy()
    normals = range(0, u.size, 3)
    u_before = np.empty(u.size // 3)
    m = np.where(np.isfinite(gain), -gain, 0.0)
    for i in normals:
        u_before[i // 3] = u[i]
        d = gain[i] * (u[i] + bias[i])
        if isc_lam is not None:
            d = d - isc_lam[i]
        new = np.maximum(start[i] + d, 0.0)
        u += A[:, i] * (new - start[i])
        lam[i] = new
    for i in normals:
        j, k = i + 1, i + 2
        t1 = lam[j] - m[j] * u[j]
        t2 = lam[k] - m[k] * u[k]
        limit = mu * lam[i]
        mag = math.sqrt(t1 * t1 + t2 * t2)
        scale = limit / max(mag, 1e-30) if mag > limit else 1.0
        t1, t2 = t1 * scale, t2 * scale
        u += A[:, j] * (t1 - lam[j]) + A[:, k] * (t2 - lam[k])
        lam[j], lam[k] = t1, t2
    return u, lam, u_before


def _sweeps(worlds, mu=0.6):
    """One sweep of the solve's kernel (``engine.core.articulated._sweep``) of
    each world of one batch packed from ``worlds``, a list of (A (k, k), u,
    lam, gain, bias, isc_lam or None) over each world's k columns (gain, bias
    and isc_lam read at the normal columns; the effective masses are -gain;
    isc_lam = 0.1 λ: the soft rows' impulse term); returns [(u, lam, u_before)]."""
    k = np.array([len(x[1]) for x in worlds])
    W, C, P = k.size, int(k.sum()), int(k.sum()) // 3
    pt_start = np.r_[0, np.cumsum(k // 3)].astype(np.int64)
    S = kernels.ArticulatedArrays(
        held=np.arange(W), pt_start=pt_start, pt_row=np.zeros(P, dtype=np.int64),
        pt_slot=np.zeros(P, dtype=np.int64), row_start=np.zeros(W + 1, dtype=np.int64),
        rows=np.zeros(0, dtype=np.int64), tree_bodies=np.zeros(0, dtype=np.int64), node=np.zeros(0, dtype=np.int64),
        order=np.zeros(0, dtype=np.int64), parent=np.zeros(0, dtype=np.int64), factors=np.zeros(W, dtype=np.int64),
        Dinv=np.zeros((0, 0, 6, 6)), L=np.zeros((0, 0, 6, 6)), M=np.zeros((W, 0, 6, 6)),
        body=np.zeros(C, dtype=np.int64), J=np.zeros((C, 6)),
        A=np.concatenate([A.T.ravel() for A, *_ in worlds]), a_start=np.r_[0, np.cumsum(k * k)].astype(np.int64),
        m=np.concatenate([np.where(np.isfinite(g), -g, 0.0) for _, _, _, g, _, _ in worlds]),
        mu=np.full(P, mu), finite=np.array([bool(np.isfinite(A).all()) for A, *_ in worlds]))
    out = []
    for w, (A, u, lam, gain, bias, isc_lam) in enumerate(worlds):
        u, lam = u + 0.0, lam.copy()
        u_before = np.empty(u.size // 3)
        soft = isc_lam is not None
        isc = np.full(u.size // 3, 0.1) if soft else np.zeros(u.size // 3)
        kernels._sweep(S, w, u, lam, lam.copy(), np.ascontiguousarray(gain[::3]), np.ascontiguousarray(bias[::3]),
                       isc, soft, u_before)
        out.append((u, lam, u_before))
    return out


def _random_world(rng, c, overflow=False):
    """Random sweep inputs of one world with c columns: A = R Rᵀ / c + I, exact
    zeros in u and λ, separating points (bias 5: their λ_n stays 0) and, with
    ``overflow``, an infinite entry of A in a separated point's column (so its
    change is an exact 0: inf · 0 must still reach u, as NaN)."""
    R = rng.normal(size=(c, c))
    A = R @ R.T / c + np.eye(c)
    u = rng.normal(size=c) * rng.integers(0, 2, size=c)
    lam = np.abs(rng.normal(size=c)) * rng.integers(0, 2, size=c)
    gain = -1.0 / np.diag(A)
    bias = rng.normal(size=c) * 0.3
    bias[::3] = np.where(rng.random(c // 3) < 0.4, 5.0, bias[::3])
    lam[::3] = np.where(bias[::3] == 5.0, 0.0, lam[::3])
    if overflow:
        sep = np.flatnonzero(bias[::3] == 5.0)
        if sep.size:
            A[0, 3 * sep[0]] = np.inf  # row 0 of column 3 sep[0]
    return A, u, lam, gain, bias


def test_a_world_alone_sweeps_as_in_a_batch_bit_for_bit_even_with_non_finite_A():
    """The solve's sweep of a world alone, of the same world packed among
    others, and the sweep written out plainly (``_reference_sweep``, which
    skips no column): the same u, impulses and normal velocities, bit for
    bit (zero signs included), over random columns with unchanged
    (separated) points, and with an infinite entry of A in a column whose
    impulse does not change: inf · 0 must still reach u (NaN), alone and in
    the batch, not be skipped away; the batch's other worlds are not
    touched by it."""
    rng = np.random.default_rng(5)
    overflowed = 0
    for trial in range(40):
        worlds = []
        for w in range(3):
            A, u, lam, gain, bias = _random_world(rng, 3 * int(rng.integers(1, 8)), overflow=w == 0 and trial % 5 == 4)
            worlds.append((A, u, lam, gain, bias, None if trial % 2 else 0.1 * lam))
        with np.errstate(invalid="ignore"):
            batch = _sweeps(worlds)
            for w in range(3):
                alone = _sweeps(worlds[w:w + 1])[0]
                A, u, lam, gain, bias, isc_lam = worlds[w]
                reference = _reference_sweep(A, u, lam, gain, bias, isc_lam, 0.6)
                for got in (batch[w], alone):
                    for x, y in zip(got, reference):
                        assert x.tobytes() == y.tobytes()
        if not np.isfinite(worlds[0][0]).all():
            overflowed += 1
            assert np.isnan(batch[0][0]).any()
            assert np.isfinite(batch[1][0]).all() and np.isfinite(batch[2][0]).all()
    assert overflowed >= 3


def test_worlds_with_fewer_points_sweep_as_alone_bit_for_bit():
    """Worlds of a batch with 5, 3 and 1 valid points, packed without padding:
    every world ends its sweep as it does alone and as the plain sweep
    (``_reference_sweep``) gives, bit for bit."""
    rng = np.random.default_rng(11)
    for trial in range(20):
        worlds = []
        for c in (15, 9, 3):
            A, u, lam, gain, bias = _random_world(rng, c)
            worlds.append((A, u, lam, gain, bias, None if trial % 2 else 0.1 * lam))
        batch = _sweeps(worlds)
        for w in range(3):
            alone = _sweeps(worlds[w:w + 1])[0]
            reference = _reference_sweep(*worlds[w], 0.6)
            for x, y, z in zip(batch[w], alone, reference):
                assert x.tobytes() == y.tobytes() == z.tobytes()


def test_articulations_closed_by_loops_keep_body_rows_and_the_others_do_not():
    """A ring of three balls on ball joints (a loop, solved with the tree) and
    a chain of two, both resting on the ground, at ``engine.CLOSED_JOINTS``:
    the chain's contact rows are solved in contact space, the ring's keep the
    body-by-body sweep (the response knows the tree rows only)."""
    b = e.SceneBuilder()
    b.add_ground()
    r = 0.05
    ring = [(0.0, 0.0), (0.2, 0.0), (0.1, 0.17)]
    for i, (x, y) in enumerate(ring):
        b.add_body(f"ring{i}", e.Sphere(r), mass=1.0, position=(x, y, r))
    for i in range(3):
        (x0, y0), (x1, y1) = ring[i], ring[(i + 1) % 3]
        b.add_ball(f"ring_j{i}", f"ring{i}", f"ring{(i + 1) % 3}", anchor=((x0 + x1) / 2, (y0 + y1) / 2, r))
    for i in range(2):
        b.add_body(f"chain{i}", e.Sphere(r), mass=1.0, position=(1.0 + 0.2 * i, 0.0, r))
    b.add_ball("chain_j", "chain0", "chain1", anchor=(1.1, 0.0, r))
    model = b.build().with_settings(**e.CLOSED_JOINTS)
    assert model.joints.loop_rows is not None
    state = model.initial_state(1)
    e.step(model, state)
    rows, _, art = _prepared(model, state)
    assert not art.empty
    names = {model.body_names[i] for i in rows.b[art.rows]}
    assert names == {"chain0", "chain1"}


def test_contacts_read_the_velocities_the_joint_solve_leaves():
    """The contact columns are read as J_c P v, P v = v - M⁻¹J_tᵀK⁻¹J_t v the
    velocities projected onto the tree joints' rows (computed here with dense
    linear algebra from the tree's row blocks and metric), not as J_c v: the
    contacts are solved before the joints, and a motor torque applied in the
    substep turns a light foot freely until the joint solve takes that back."""
    model, state, *_ = _drop(1, 0.5, articulated_contacts=True, **RIGID)
    _, joints, art = _prepared(model, state)
    assert not art.empty
    rng = np.random.default_rng(0)
    moving = model.dynamic
    state.velocity[:, moving] += rng.normal(0.0, 0.5, state.velocity[:, moving].shape)
    state.angular_velocity[:, moving] += rng.normal(0.0, 3.0, state.angular_velocity[:, moving].shape)
    tree = joints.tree
    a, b, _, _, _, _, _, Ja, Jb, mask = tree.blocks(joints, state, tree)
    N = model.num_bodies
    J_t = np.zeros((a.size * 6, N * 6))
    for j in range(a.size):
        for r in np.flatnonzero(mask[0, j]):
            J_t[6 * j + r, 6 * a[j]:6 * a[j] + 6] += Ja[0, j, r]
            J_t[6 * j + r, 6 * b[j]:6 * b[j] + 6] += Jb[0, j, r]
    J_t = J_t[np.abs(J_t).sum(axis=1) > 0]
    cols = (6 * tree.t.bodies[:, None] + np.arange(6)).ravel()  # the tree's bodies' coordinates
    J_t = J_t[:, cols]
    M = np.zeros((cols.size, cols.size))
    for k in range(tree.t.bodies.size):
        M[6 * k:6 * k + 6, 6 * k:6 * k + 6] = tree.M[0, k]
    v = np.concatenate((state.velocity[0], state.angular_velocity[0]), axis=-1).reshape(-1)[cols]
    M_inv_Jt = np.linalg.solve(M, J_t.T)
    Pv = v - M_inv_Jt @ np.linalg.solve(J_t @ M_inv_Jt, J_t @ v)
    assert np.abs(J_t @ Pv).max() < 1e-9 * np.abs(v).max()
    projected = np.zeros((N, 6))
    projected[tree.t.bodies] = Pv.reshape(-1, 6)
    S = art.arrays
    expected = np.einsum("ck,ck->c", S.J, projected[S.body])
    raw = np.einsum("ck,ck->c", S.J, np.concatenate((state.velocity[0], state.angular_velocity[0]),
                                                     axis=-1)[S.body])
    got = art.velocities(state)
    scale = np.abs(expected).max()
    assert np.abs(got - expected).max() <= 1e-9 * scale
    assert np.abs(raw - expected).max() > 0.1 * scale  # the unprojected reading differs: the test can fail


def test_column_velocities_match_the_joint_solve_across_worlds_with_uneven_contacts():
    """Three hinged boxes (no limits: the joint solve is the projection P
    alone) in three worlds, the second lifted clear of the ground, so that
    the worlds' column counts differ: with random velocities, each world's
    columns, packed world by world, read what J_c gives after the joint solve
    itself (rigid rows, no bias). The lifted world has no columns at all
    (the first world's middle box is lifted a little too, so its columns are
    fewer than the third's)."""
    model = scenarios.hinged_boxes(masses=(1.0, 2.0, 3.0), articulated_contacts=True, **RIGID).build()
    state = model.initial_state(3)
    state.position[1, 1:, 2] += 1.0
    state.position[0, 1, 2] += 0.5
    _, joints, art = _prepared(model, state)
    assert not art.empty
    S = art.arrays
    counts = 3 * np.diff(S.pt_start)  # columns per world
    assert counts[2] > counts[0] > 0 and counts[1] == 0
    rng = np.random.default_rng(1)
    state.velocity[:, 1:] += rng.normal(0.0, 0.5, state.velocity[:, 1:].shape)
    state.angular_velocity[:, 1:] += rng.normal(0.0, 3.0, state.angular_velocity[:, 1:].shape)
    got = art.velocities(state)
    world = np.repeat(np.arange(3), counts)  # the world of each column
    raw = np.einsum("ck,ck->c", S.J, np.concatenate((state.velocity, state.angular_velocity),
                                                     axis=-1)[world, S.body])
    joints.solve(model, state, model.settings.dt / model.settings.substeps, False)
    v = np.concatenate((state.velocity, state.angular_velocity), axis=-1)
    expected = np.einsum("ck,ck->c", S.J, v[world, S.body])
    scale = np.abs(expected).max()
    assert np.abs(got - expected).max() <= 1e-9 * scale
    assert np.abs(raw - expected).max() > 0.1 * scale


def test_more_sweeps_converge_on_the_soft_contacts_of_a_resting_chain():
    """Three hinged 10 kg boxes resting flat at dt 1/30 (rigid joints, no
    limits): each Box2D soft-step update is an exact Gauss-Seidel update of
    the regularised system, so further sweeps converge on it and the chain
    rests a little shallower (measured 0.241 mm with 1 sweep, 0.205 with 8)."""
    def depth(sweeps):
        model = scenarios.hinged_boxes(masses=(10.0, 10.0, 10.0), dt=1 / 30, articulated_contacts=True,
                                       articulated_contact_sweeps=sweeps, **RIGID).build()
        state = model.initial_state(1)
        for _ in range(90):
            e.step(model, state)
        assert np.abs(state.velocity).max() < 1e-6
        return float(scenarios.ground_penetration(model, state)[0])

    one, eight = depth(1), depth(8)
    assert 1e-4 < eight < 0.9 * one < 3e-4


def test_response_matches_dense_linear_algebra_and_a_world_alone_the_batch():
    """The responses and A of the kernels against the textbook formulas in
    dense linear algebra, per world: Z = M⁻¹J_cᵀ - M⁻¹J_tᵀ (J_t M⁻¹ J_tᵀ)⁻¹
    J_t M⁻¹J_cᵀ, A = J_c Z, m = 1 / A_ii (to rounding: the kernels solve
    through the tree's block factors), on three hinged boxes in three worlds with uneven
    contacts; and each world's Z, A and m computed alone equal the batch's
    bit for bit."""
    model = scenarios.hinged_boxes(masses=(1.0, 2.0, 3.0), articulated_contacts=True, **RIGID).build()
    state = model.initial_state(3)
    state.position[1, 1:, 2] += 1.0
    state.position[0, 1, 2] += 0.5
    state.orientation[2, 2] = [math.cos(0.1), math.sin(0.1), 0.0, 0.0]  # a tilted box: fewer, uneven points
    batch_state = state.copy()
    _, joints, art = _prepared(model, batch_state)
    S = art.arrays
    tree = joints.tree
    a, b, _, _, _, _, _, Ja, Jb, mask = tree.blocks(joints, batch_state, tree)
    N = model.num_bodies
    cols = (6 * tree.t.bodies[:, None] + np.arange(6)).ravel()  # the tree's bodies' coordinates
    checked = 0
    for w in range(3):
        c = art.columns(w)
        if c.stop == c.start:
            continue
        J_t = np.zeros((a.size * 6, N * 6))
        for j in range(a.size):
            for r in np.flatnonzero(mask[w, j]):
                J_t[6 * j + r, 6 * a[j]:6 * a[j] + 6] += Ja[w, j, r]
                J_t[6 * j + r, 6 * b[j]:6 * b[j] + 6] += Jb[w, j, r]
        J_t = J_t[np.abs(J_t).sum(axis=1) > 0][:, cols]
        J_c = np.zeros((c.stop - c.start, N * 6))
        for i, col in enumerate(range(c.start, c.stop)):
            J_c[i, 6 * S.body[col]:6 * S.body[col] + 6] = S.J[col]
        J_c = J_c[:, cols]
        M = np.zeros((cols.size, cols.size))
        for k in range(tree.t.bodies.size):
            M[6 * k:6 * k + 6, 6 * k:6 * k + 6] = S.M[w, k]  # the batch's metric
        U = np.linalg.solve(M, J_c.T)
        MJt = np.linalg.solve(M, J_t.T)
        Z = U - MJt @ np.linalg.solve(J_t @ MJt, J_t @ U)
        got = art.response(w).reshape(c.stop - c.start, 6 * N)
        assert np.abs(got[:, cols] - Z.T).max() <= 1e-12 * np.abs(Z).max()
        assert not np.delete(got, cols, axis=1).any()  # the ground does not move
        A = J_c @ Z
        assert np.abs(art.delassus(w) - A).max() <= 1e-12 * np.abs(A).max()
        assert np.allclose(S.m[c], 1.0 / np.diag(A), rtol=1e-12, atol=0.0)
        # The same world alone.
        alone = model.initial_state(1)
        for key in ("position", "orientation", "velocity", "angular_velocity"):
            alone.arrays[key][0] = state.arrays[key][w]
        _, _, art1 = _prepared(model, alone)
        S1 = art1.arrays
        assert art1.response(0).tobytes() == art.response(w).tobytes()
        assert art1.delassus(0).tobytes() == art.delassus(w).tobytes()
        assert S1.m.tobytes() == S.m[c].tobytes()
        checked += 1
    assert checked == 2
