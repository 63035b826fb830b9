"""Accuracy and solver settings of a model: the knobs of the accuracy report.

All are plain values on a frozen dataclass; ``Model.with_settings(**changes)``
gives a model with other settings and the same scene.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, fields

INTEGRATORS = ("symplectic", "euler", "rk4")
SOLVERS = ("soft_step", "thesis")
JOINT_SOLVERS = ("tree", "gauss_seidel")
JOINT_LOOPS = ("exact", "gauss_seidel")
CONTACT_COLORINGS = ("ordered", "greedy")

#: Settings for accuracy over speed (``Settings(**ACCURATE)``): rigid tree
#: joints with their limits inside the tree solve, at 16 substeps. Measured
#: (tests/engine/test_joints.py, benchmarks.accuracy; figures in the README):
#: humanoid in free fall under bang-bang maximum torques for 10 s: anchor
#: error under 1 mm and limits within 0.98° (seeds 1, 2: 0.61° and 0.98°).
#: Without limit rows outside the tree the humanoid in the air is a free
#: articulation; ACCURATE gives it no geometric stiffness: at 16 substeps and
#: a 0.2 mm slop the 100:1 chain released from horizontal holds 0.19 mm
#: without it, and since the stiffness takes the smaller of the loads before
#: and after each biased solve (``JointSet.positions_moved``) it let the
#: humanoid pass a limit by 2.25° (seed 2; 0.82° while it took the load after
#: the solve). At 12 substeps it
#: held 0.7° until the joint dampers stopped absorbing motor torque; with the
#: torques in full, 12 substeps let the limits pass by 3.5-3.9° (8 substeps,
#: before: 1.5-2.4°: a light foot crosses its swing cone within a substep).
#: At 12 substeps it cost 2.7 times the default on the ragdoll.
#: With the joint post-stabilisation at a 0.2 mm slop (``joint_projection_*``,
#: below; ``SOFT_JOINTS`` projects only beyond 4 cm) the humanoid under random
#: maximum torques on the ground keeps every anchor within 0.20 mm (without:
#: 9.1 mm with body-by-body contacts, 8 worlds x 200 steps; 0.53 mm with the
#: articulated contacts below, 2 worlds x 40) for 5% more time per step.
#: The contacts of articulations on static bodies are solved with the
#: articulation's response (``articulated_contacts``, as in ``CLOSED_JOINTS``):
#: the body-by-body Gauss-Seidel contacts fight rigid joints solved before
#: them and share no friction load through them. With those, the six drops of
#: ``benchmarks.stability --quick`` ragdoll_drops still moved at 0.29 m/s
#: 5-7 s after them and landed 4.3 cm deep, and three hinged boxes on a 24°
#: incline (μs 0.5) crept 4.2 mm in 5 s; with these, 0.023 m/s (the bound
#: 0.02), 1.7 cm and no creep (tests/engine/test_contacts.py), for 4-11% more
#: time per step on the ragdoll. Deeper with these: the 100 m/s impact (23
#: against 16 cm, a body at 4.25 against 2.15 m/s 3-4 s after it) and the
#: ragdoll under random maximum torques (6.4 against 5.8 cm).
ACCURATE = {"substeps": 16, "joint_hertz": math.inf, "joint_limits_in_tree": True, "joint_projection_slop": 0.0002,
            "free_joint_projection_slop": 0.0002, "free_joint_geometric_stiffness": False,
            "articulated_contacts": True, "articulated_contact_sweeps": 1}

#: The defaults since 2026-12-04, spelled out (``Settings(**CLOSED_JOINTS)``
#: steps as ``Settings()`` does; it sets True where the defaults' None means
#: "on wherever it can act", so with the Gauss-Seidel joint solver or the
#: thesis solver it is an error): rigid tree joints with their limits in the tree solve,
#: the 0.2 mm post-stabilisation of ``ACCURATE`` for articulations touching
#: something or driven by a motor, and the contacts of articulations on static
#: bodies solved with the articulation's response (``articulated_contacts``,
#: two sweeps), so that they do not fight the rigid joints; its contacts are
#: solved before its joints (``step``), so the limits hold exactly at the end
#: of each solve. Measured while it was a preset (free articulations then
#: projected at 0.2 mm too) against the old defaults (``SOFT_JOINTS``; README,
#: "Articulated contacts"): benchmarks.accuracy's ragdoll under random torques
#: keeps its joint anchors within 0.2 mm (4.0 cm), its limits give by 0.63 rad
#: (ACCURATE 0.005); every ragdoll case of ``benchmarks.stability --quick``
#: holds 0.2 mm, the 100 m/s impact too (3.2 cm deep; the body then skids
#: 52 m and rests by 4.5 s); dropped ragdolls land 2.0-2.5 cm deep (3.2-3.5)
#: and rest. With one ``articulated_contact_sweeps`` its drops landed 4.7-5.2
#: cm deep and the impact 18.7 cm; with more, limbs pressed against limits the
#: response does not know sink further (README). The step costs 1.4-1.5 times
#: ``SOFT_JOINTS``' for one ragdoll on the ground and 1.9 times at 64 worlds
#: (``benchmarks.throughput --worlds 1 64 --scenes ragdoll_ground``), and its
#: contact response matrices take 195-225 KB per world (64-91).
CLOSED_JOINTS = {"joint_hertz": math.inf, "joint_limits_in_tree": True, "joint_projection_slop": 0.0002,
                 "articulated_contacts": True, "articulated_contact_sweeps": 2}

#: The defaults before 2026-12-04 (``Settings(**SOFT_JOINTS)``), kept for
#: speed: an articulation touching something is soft (60 Hz, damping ratio 2),
#: its limits are Gauss-Seidel rows after the tree solve, its contacts are
#: solved body by body and its anchors are projected back only beyond 4 cm.
#: The step costs 0.27-0.66 of the defaults' on a ragdoll on the ground (W =
#: 1024 to 1; 63 against 200 KB per world); the
#: ragdoll's joint anchors open by 4.0 cm under random torques (defaults
#: 0.2 mm) and the standing PD on Balance falls more often (README).
SOFT_JOINTS = {"joint_hertz": 60.0, "joint_limits_in_tree": False, "joint_projection_slop": 0.04,
               "articulated_contacts": False, "articulated_contact_sweeps": 1,
               "static_contact_projection_depth": math.inf}


@dataclass(frozen=True)
class Settings:
    """Step settings.

    The defaults changed on 2026-12-04 to rigid tree joints with their limits
    in the tree solve, a 0.2 mm post-stabilisation for articulations touching
    something or driven by a motor, and the contacts of articulations solved
    with the articulation's response at two sweeps (what ``CLOSED_JOINTS``
    names): the ragdoll under random torques keeps its joints within 0.2 mm
    (4.0 cm before) for 1.3-1.9 times the step. The old defaults are
    ``SOFT_JOINTS``. Figures below said to be "at the defaults" were measured
    with the defaults of their time; those before that date hold for
    ``SOFT_JOINTS``.

    dt: seconds per step.
    substeps: substeps per step; each integrates, solves and relaxes once.
    iterations: constraint sweeps per substep in the biased solve.
    relax_iterations: constraint sweeps per substep in the relax (unbiased) solve.
    free_contact_relax_passes: further relax passes, after those sweeps, over
        the contact rows whose bodies carry no joints (boxes, balls, the
        ground). The relax solve takes back the velocity the position bias
        added; one Gauss-Seidel pass leaves part of it, which kept piles of
        free bodies rocking. Measured at the defaults, without and with the
        pass: a stack of 5 boxes 0.025 -> 0.0003 m/s over 2-3 s; the 1 kg box
        between two 100 kg ones 0.34 -> 0.024 m/s over its 5 s (penetration
        2.9 -> 0.95 cm); the 10-row pyramid, which swayed at 0.25 m/s,
        0.006 m/s; 20 boxes created inside each other fling none faster than
        1.2 m/s (2.0 before).
        It costs a scene of free boxes about 45% more per step (W = 1) and a
        scene without such rows nothing. 6 substeps rest those scenes as well
        at about the same cost, but every scene pays for them. Rows on a
        jointed body keep one pass: a contact pass after the joints' relax sees
        a single bone's mass with no joint solve after it, and a dropped
        ragdoll then moved at 0.037 m/s 3-5 s after landing instead of 0.011.
    integrator: "symplectic" (semi-implicit Euler, default), "euler" (the
        thesis's explicit Euler, equations 4 and 5), or "rk4" (classical
        Runge-Kutta on the force effects of free motion).
    solver: "soft_step" (Catto's soft step, default) or "thesis" (sequential
        impulses with mass-ratio split of penetration, the baseline).
    joint_solver: "tree" (default: the point and lock rows of each articulation
        solved exactly per sweep by a linear-time block factorisation in tree
        order, Baraff 1996; joints closing loops: ``joint_loops``) or
        "gauss_seidel" (one 3x3/2x2 block per joint per sweep, colour order).
        Limits are Gauss-Seidel rows after the tree solve, or rows of it
        (``joint_limits_in_tree``, the default with "tree"). Only the soft
        step uses it.
    joint_loops: with the tree solver, "exact" (default): the rows of joints
        that close a loop (a grid, a four-bar, a chain pinned at both ends)
        are solved together with the tree rows, exactly, through the dense
        Schur complement of the loop rows (Baraff 1996); "gauss_seidel": they
        are Gauss-Seidel rows after the tree solve, as before (and in a scene
        whose tree joints have limits in the tree, such as the defaults'
        humanoid scenes). Either way an articulation with loops is soft
        (``joint_hertz``, which is inf by default, so only when set;
        ``loop_joint_hertz`` when its loops are solved exactly): rigid, with its
        loops solved exactly, it held its joints less well (``benchmarks.
        stability`` chain_loop, a 20 kg ball on a slack chain pinned at both
        ends: 3.0 mm against 1.1 mm over 10 s; the grid below 29 mm against
        12 mm). Measured over 10 s: the
        10x10 grid of ball joints pinned at two corners opened by 12.4 mm
        exact against 39.8 mm (10 km out 12.4 mm; 22.3 mm since later
        factorisation changes, a spike at 1.9 s whose size moves with
        rounding: README hard cases), for about 2.5 times the
        step cost (one dense solve of 3 rows per ball-joint loop per sweep);
        chain_loop 1.1 mm against 10.8 mm. Its temporaries grow with bodies x
        loop rows, about 11 MB per world for that grid (nothing for a scene
        without loops); batches go through in chunks of worlds of at most
        256 MB. Exact loop rows take the softness of their articulation's
        tree joints (``loop_joint_hertz``; the grid 0.91 cm since), also
        where the other articulations' tree joints are rigid (``ACCURATE``,
        ``CLOSED_JOINTS``; rigid loop rows gained energy: the grid 103 J in
        10 s at ``ACCURATE``, 11 J with the regularisation below at 1e-3):
        with the 0.2 mm post-stabilisation of those presets the full 10 s
        held the grid within 1.2 mm at ``CLOSED_JOINTS`` and 0.20 mm at
        ``ACCURATE`` (chain_loop 0.20 mm at both; left Gauss-Seidel, as they
        were before, 7.5 cm in 2 s and 1.85 cm in 3 s at ``CLOSED_JOINTS``),
        the grid's step at ``ACCURATE`` 3.2 times as long as with
        Gauss-Seidel loop rows (161 against 50 s for the 10 s). Not when
        ``joint_limits_in_tree`` puts limits of the scene in the tree (the
        loop solve has no active set): those loops stay Gauss-Seidel. Redundant loop rows (a chain pinned taut at both
        ends, the grid's pinned edge) carry a load along the redundant
        direction that the regularisation (1e-6 of the largest diagonal
        entry), not the physics, sets: it moves nothing, but a break threshold
        reads it (a taut 3-link chain of 2.9 N: up to 1400 N). For breakable
        joints in such loops use "gauss_seidel", with the presets too.
    joint_geometric_stiffness: with the tree solver, add to every tree joint
        (free articulations: ``free_joint_geometric_stiffness``) its
        geometric stiffness h²|F|(|r|² I - r rᵀ)/|r| to the inertia its bodies
        show the joint solve (Andrews et al. 2017), which stabilises light links
        between heavy loads (the zigzag mode of a chain under tension). Off by
        default: it fixes the 100:1 chain released from horizontal at 4
        substeps with soft joints (317 mm -> 0.4 mm anchor error) but made the humanoid under
        maximum torques and the hinge-limit test worse in measurements.
    joint_geometric_stiffness_cap: that added inertia is capped at this many
        times the body's own (trace ratio); without a cap the load and the
        stiffness can feed each other under violent motor torques.
    joint_limits_in_tree: with the tree solver and rigid limits (limit_hertz
        inf; otherwise a ValueError), solve the twist and swing limit
        rows inside the tree solve (one more row in each joint's free angular
        slots) with an active set, instead of Gauss-Seidel rows after it. Measured when it was off by default: single limited joints
        improve (ball into its limits at 50 N·m: 1.1° vs 2.2° over the limit;
        rigid joints 0.14°), and with rigid joints at 8 substeps the humanoid
        under bang-bang maximum torques keeps its limits within 1.5-2.4° (GS
        rows: 7°); with soft joints the soft equality rows and the rigid limit
        rows of one solve disagree, and at 4 substeps a light foot still
        swings 16° past its cone within a substep. None (the default): on
        wherever it can act (tree joint solver, soft step, rigid limits);
        False in ``SOFT_JOINTS``.
    joint_active_set_passes: most passes of that active set per solve (each a
        small solve in the limit rows' space on the tree's one factorisation per
        set of positions; 5 converged every solve of a humanoid in the air under
        random maximum torques, 3 left rows closing at up to 9 rad/s; but with 5
        ``CLOSED_JOINTS``' six drops rested worse, 0.020 against 0.008 m/s from 5 s).
    joint_hertz, joint_damping_ratio: softness of the joints the tree solver
        solves in an articulation that Gauss-Seidel rows act on or that
        has loops: a contact this step, a limit outside the tree, a
        loop-closing joint (Hz, -; loop rows solved exactly take their
        articulation's softness);
        capped at half the substep rate (hω <= π); ``joint_hertz = inf`` (the
        default) makes them rigid (full bias C/h). Rigid joints need
        ``articulated_contacts``: with body-by-body contacts (which see one
        body's mass) they and the exact tree solve fight, a dropped ragdoll
        chatters at 5-9 cm/s 3-6 s after landing, and the joints share no
        friction load between bodies on the ground (three hinged boxes slide
        off a 24° incline that holds each box alone,
        ``tests/engine/test_contacts.py``). ``SOFT_JOINTS`` (the defaults
        before 2026-12-04) has 60 Hz, ζ 2: a soft joint carries load by its
        stretch, 4 cm under random torques.
    loop_joint_hertz, loop_joint_damping_ratio: the same for an articulation
        with loop-closing joints solved with the tree (``joint_loops``
        "exact"), its tree and loop rows alike; capped at half the substep
        rate like joint_hertz. At 60 Hz and damping ratio 2 (SOFT_JOINTS' joint_hertz) the
        10x10 sphere grid's free edge, whipping through at 12 m/s 1.9 s after
        release, stretched the joints by 2.23 cm; at 120 Hz and 1.0 (the
        defaults; the cap at 4 substeps of 1/60 s) 0.91 cm (10 km out 0.69
        cm against 1.5), at 120 Hz and 2.0 1.42 cm, 5.0 1.75 cm
        (benchmarks.stability sphere_grid; stiffer than the cap, rigid loop
        rows gained energy: see joints).
    free_joint_hertz: the same for an articulation nothing else acts on (a
        pendulum, a chain in the air); default inf, rigid: a soft pendulum's
        period was 0.34% long and it lost 9% of its energy in 60 s (rigid:
        under 0.04% and 0.5%), and a 100:1 ball and chain opened by 2.5 cm (rigid
        with geometric stiffness: 3.0 mm over 10 s).
    free_joint_geometric_stiffness: add geometric stiffness (below) to the
        joints of those free articulations; on by default: rigid joints
        without it let the 100:1 chain released from horizontal open by
        231 mm (with it 9.6 mm); off in ACCURATE, whose 16 substeps and
        0.2 mm post-stabilisation hold that chain within 0.19 mm without it.
    gs_joint_hertz, gs_joint_damping_ratio: softness of the joints solved by
        Gauss-Seidel rows: those closing loops with ``joint_loops``
        "gauss_seidel", and all of them with joint_solver "gauss_seidel"
        (default 60 Hz, ζ 2; stiffer loop rows fight the exact tree solve: a
        10x10 grid of ball joints gained 127 J at 240 Hz).
    joint_relax: run the joint equality rows in the relax solve too (limit
        rows always run). On by default; off, a joint's soft bias velocity
        lives one substep longer (measured no energy gain) and the joints cost
        half as much per substep, which pays for twice the substeps.
    joint_projection_passes: post-stabilisation of the tree joints at the end
        of each step (``engine.joint_projection``): at most this many exact
        Gauss-Newton passes move the positions, not the velocities, back onto
        the joints, in the worlds where an error exceeds the slop; 0 turns it
        off. A world's passes stop once its error beyond the slop is within
        1% of the slop (``joint_projection.TOLERANCE``; two passes in most
        projected steps under random maximum torques), so the most passes
        cost only where they are needed: where a static contact projection
        moved a limb far, 4 passes left the joints open and the move was
        undone, the limb left in the ground (docs/decisions.md). Default 8
        passes. With
        a 4 cm slop (``SOFT_JOINTS``, the default slop before 2026-12-04) it
        was a safety net for extremes:
        the ragdoll hitting the ground at 100 m/s keeps its joints within
        4.3 cm (0.51 m without; penetration after impact 3.1 cm against
        0.9 cm), ragdolls dropped from 0.5-1.5 m open by 3.8-4.0 cm instead
        of 5.8-6.5 cm (feet 2.7-2.9 cm deep, against 2.3-2.4) and rest as
        before, and
        the Balance task, whose joints stay within the slop, steps exactly as
        without it (the standing PD: the same 3 falls in 40 pushed episodes).
        Under random maximum torques it holds the anchors at 4 cm (without it
        82 mm, median over 16 worlds x 300 steps) but the flailing limbs went deeper into the
        ground (median 78 mm against 65), and the 1/30 s drop's feet sank 4.0
        cm against 2.8. Costs 1-3% per step while no world needs it.
        That was the default with soft joints; the default now is 0.2 mm
        (rigid joints, as ``ACCURATE``), for the joints of articulations
        touching something or driven by a nonzero motor torque this step
        (``free_joint_projection_slop`` for the others). A smaller slop does
        not suit soft joints (``SOFT_JOINTS``): a soft joint
        carries its load by its stretch, and projecting the stretch away
        changed the Balance task (slop 5 mm: the standing PD fell in 12 of 40
        pushed episodes instead of 3) and, at 1-2 cm, left a dropped ragdoll in
        poses that chatter at 0.1-0.4 m/s.
    free_joint_projection_slop: m, the slop for the joints of articulations
        nothing touches and no motor drives this step (a passive pendulum or
        chain in the air). Default 4 cm: the projection moves positions, not
        velocities, and a velocity left off the moved joints' manifold is
        taken out by the next rigid solve, so a tight slop drains energy from
        a fast passive chain: the undamped double pendulum lost 16% of 2 m g L
        over 20 s at 0.2 mm (2.1% at 4 cm, anchors within 1.3 mm;
        ``tests/engine/test_joints.py``). The ragdoll under random torques
        leaves the ground and, at 4 cm here, opened by 4.1 mm in the air; it
        is driven, so it takes joint_projection_slop (0.2 mm).
    joint_projection_slop: m; only the part of an anchor error beyond it is
        projected (the lock rows' angular error beyond slop / 0.25 m rad).
    joint_projection_contact_weight: in the projection's metric, each contact
        point within 1 cm of touching adds this many times its body's mass
        against moving that point along the contact normal (ramped to 0 at
        1 cm; a face resting on its 4 points adds it 4 times): without it the
        projection closed a landing ragdoll's stretched ankle by turning the
        light foot 13 cm into the ground (14 mm with it).
    limit_hertz: softness of joint limits (Hz, damping ratio
        gs_joint_damping_ratio); default inf, rigid, so a
        joint driven into its limit by its maximum torque holds the limit.
    limit_soft_margin: rad; a Gauss-Seidel limit row (limits outside the
        tree) of an articulation with a contact this step is as soft as its
        tree joints (``joint_hertz``, ``joint_damping_ratio``) while violated
        by less than this, and rigid (``limit_hertz``) beyond; 0 turns it off,
        as does ``relax_iterations`` 0 (no relax solve takes back the soft
        rows' bias: at dt 1/30 with one substep, where the ragdoll of
        benchmarks.accuracy diverges anyway, its joints opened by 2e7 m within
        0.95 s, against 860 m with rigid limits).
        Soft joints against rigid limits left some ragdolls on the ground
        twitching for good: over 24 random drops (``benchmarks.stability``
        ragdoll_drops_random, seeds 1-3) three kept a limb trembling against
        its limit at 3-5.5 cm/s 7 s after the drop. With the margin every one
        of them moves under 0.5 cm/s from 5 s (seed 2: 0.52 cm/s against 5.5;
        ragdoll_drops 0.016 against 4.1 cm/s); the standing PD on Balance fell
        in 19 of 200 default-push episodes against 18, and the quick ragdoll
        hard cases keep their joints at the 4 cm projection slop. Out of
        contact limits stay rigid: a hinge driven into its limit at 50 N·m
        passes it by under 1° (soft within 0.05 rad everywhere: 2.5°; soft
        everywhere at 60 Hz, the humanoid under random maximum torques swung
        its limbs through their cones and opened its joints by 1.2 m).
    joint_max_push_out, joint_max_angular_push_out: m/s and rad/s, the
        largest speed a joint's (or violated limit's) position bias may add.
        Without them a joint pulled far apart, e.g. a ragdoll hitting the
        ground at 100 m/s with rigid limits, was driven back at C/h, turned
        its links by radians in one substep and diverged within three steps.
    contact_coloring: how each step's contact rows are split into colours,
        the sets of rows swept together (no moving body twice in one).
        "ordered" (default): the rows are swept one after another in pair
        order, in parallel only where independent; a chain of rows sharing
        bodies takes a colour per row (a stack of 20 boxes 19 colours, the
        10-row pyramid 50). "greedy": first-fit colours (Box2D v3), at most
        one more than the most rows a row shares a body with (the stack 2,
        the pyramid 7), rows taken top down. Greedy against ordered, one
        world (step time: median of 3 alternating runs of 20 steps after 1 s;
        figures: ``benchmarks.stability`` full runs):
        the step 7.5 times cheaper on the stack of 20, 5.9 on the pyramid,
        3.2 on the 1/30 s stack of 10, 1.9 on the overlapping pyramid and the
        pile of ragdolls; the pyramid at rest as well (0.005 against
        0.006 m/s), the 100:1:100 sandwich sooner (0.001 against 0.024 m/s
        after 1 s), the pile of ragdolls 4.5 cm deep against 5.2 (joints
        2.8 cm against 1.9). But a change crosses a chain swept in two
        colours only two rows per sweep: before the contacts' load
        stiffening the stack of 20, which slowly buckled ordered (0.11 m/s
        by 10 s), fell over (3 m/s; with it both rest, greedy at 0.0093 m/s
        and 8.6 times cheaper, ordered at 0.0084), and piles
        pushed apart move faster: 20 boxes created inside each other fling
        one at 4.5 m/s beyond its fall (ordered 1.2; bound 2), the
        overlapping pyramid at 1.7 m/s (0.46). Scenes whose rows all have a
        static side (a ragdoll alone on the ground, the Balance task) colour
        the same either way.
    contact_hertz, contact_damping_ratio: softness of contacts; the contact
        stiffness used is min(contact_hertz, substep rate / 4) as in Box2D v3.
    contact_load_stiffening: the largest factor on the position-bias rate (the
        spring) of a contact point between bodies without joints that carries
        more than the weight of its own effective mass, raised in proportion
        to that load (``ContactRows._bias_rate``; 1 turns it off). A soft
        point's spring is its effective mass times ω², so a column of light
        boxes sags at every contact under the load above it and slowly
        buckles: the stack of 20 1 kg boxes moved at 0.11 m/s by 10 s
        without it, under 0.01 m/s with 1.25 (full 10 s runs of
        ``benchmarks.stability``), with the 10-row pyramid and the 100:1:100
        sandwich still at rest (0.010 and 0.023 m/s from their rest times).
        Larger factors fail where a light body carries a heavy one: at 1.5
        the sandwich's 1 kg box rocked at 0.26 m/s (its points carry 100
        times their effective mass), and contacts stiffer by 1.44 (72 Hz)
        everywhere did the same. Rows on jointed bodies (ragdolls, the
        Balance task) keep the plain spring, and so does every row without a
        relax solve (relax_iterations 0), which would keep the stiffer bias's
        velocity: the 10-box stack of ``benchmarks.accuracy`` then sank 0.4 m
        (2.1 mm with the plain spring).
    articulated_contacts: solve the contacts of articulations on static
        bodies (a ragdoll on the ground) in contact space with the
        articulation's response through the joint tree
        (``engine.articulated_contacts``; it needs joint_solver "tree" and
        solver "soft_step", else a ValueError) instead of one body's mass.
        None (the default): on wherever it can act (tree joint solver, soft
        step); False in ``SOFT_JOINTS``. With rigid joints it keeps them closed on the ground:
        ``ragdoll_drops`` with rigid tree joints, limits in the tree and a
        0.2 mm projection slop opened 6.1 cm and still moved at 0.42 m/s
        after 3 s, with it 0.2 mm and 0.082 m/s (joints solved first, as
        then); with its contacts solved before the joints (``step``, now,
        every contact row of the scene, the body-by-body ones too) and its
        columns reading the velocities the joint solve leaves
        (``ArticulatedContacts._velocities``) they rest at 0.0088 m/s from
        5 s, and every ragdoll hard case holds 0.2 mm (quick runs; 2-9 cm
        without).
        With soft joints (``SOFT_JOINTS``) it helps little: the drops rest
        (``ragdoll_drops`` and ``ragdoll_drops_random`` 0.0089 and 0.0067 m/s
        from 5 s against 0.0002 and 0.005; 0.084 and 0.10 before the columns
        read the joint solve's velocities) and open by 2.9-3.6 cm (4.0
        without); with the joints solved first the random drops gained
        303 J. Cost (``benchmarks.throughput``, ragdoll on the ground under
        random maximum torques): with soft joints about the same at
        W = 1 and 1.1x at W = 64, with rigid joints 2.1x and 1.7x the rigid
        joints' without it (``CLOSED_JOINTS``, measured before its limits' active
        set went to one factorisation a set of positions: 1.4-1.7x and 2.1-2.5x the
        defaults'; now 1.0-1.3x and 1.75-1.78x); its per-step matrices grow with the contact rows per world. README:
        "Articulated contacts".
    articulated_contact_sweeps: projected Gauss-Seidel sweeps over the
        articulated contacts' columns per solve (each one Box2D's soft step:
        Δλ = -m ms (Ċ + bias) - isc λ with the current λ). The columns are
        coupled through the whole articulation (a foot's points through the
        body above it), and one sweep leaves their normal impulses short at
        a landing. At ``CLOSED_JOINTS`` (``benchmarks.stability --quick``,
        1 / 2 / 3 / 4 sweeps): the random drops land 5.2 / 2.5 / 1.7 /
        1.5 cm deep, the six drops 4.7 / 2.0 cm (rest from 5 s 0.0088 /
        0.00007 m/s), the 100 m/s impact 18.7 / 3.2 / 8.7 / 4.6 cm, but the
        dt 1/30 drop 5.2 / 3.5 / 6.4 / 6.7 cm and the ragdoll under random
        maximum torques 12.3 / 8.4 / 13.7 / 12.4 cm; anchors 0.2 mm
        throughout. A chain of hinged boxes resting flat (no limits) sinks a
        little less with each sweep (0.24 / 0.25 / 0.23 / 0.22 mm at dt
        1/30): the sweeps converge on the soft system. The limits are not
        in the response, and the more the sweeps trust it the harder a limb
        can be pressed against a limit the joint solve then holds: the dt
        1/30 drop without the humanoid's limits lands 5.2 / 3.5 / 1.4 / 0.46
        cm deep with 1 / 2 / 4 / 8 sweeps, with them 5.2 / 3.5 / 6.7 / 8.1.
        Two by default (and in ``CLOSED_JOINTS``); 1 in ``ACCURATE`` (not
        measured with two) and ``SOFT_JOINTS``.
    max_push_out: m/s, the largest speed the position bias may add.
    restitution_threshold: m/s, closing speeds below it do not bounce.
    linear_slop: m, penetration allowed before position correction pushes out.
    speculative_distance: m, contacts are created for gaps up to this distance
        plus the distance travelled in one step.
    static_contact_projection_depth: m; a body that ends a step deeper than
        this in a static shape is moved back out to it along the contact
        normal, positions only, before the joint projection closes the joints
        the move opened (:mod:`engine.contact_projection`; ``ROUNDS`` rounds
        of both in turn, and a world whose joints cannot follow the move is
        put back: ``joint_projection.MAX_OPENING_AFTER_MOVE``); inf: off (as
        in ``SOFT_JOINTS``). Default 0.02: under random maximum torques (16
        worlds x 500 steps) limbs went 2.4 cm deep at worst, against 10.4 cm
        without (30 steps deeper than 5 cm), joints 0.3 against 0.2 mm. Not with
        ``solver="thesis"`` (its own penetration resolution); with
        ``joint_solver="gauss_seidel"`` or ``joint_projection_passes`` 0 the
        joints a move opens are closed by the next steps' solves.
    check_finite: raise ``SimulationError`` naming the world, body and step
        when a state turns non-finite (else only flag it).
    world_chunk: most worlds stepped in one pass; a larger batch is stepped
        as consecutive slices of this many worlds (views of the state, so
        nothing is copied), each through the whole step. A world's step does
        not depend on the others, so the trajectories are bit-identical to
        one pass; the events come slice by slice, and an exception in a
        slice (a ``FloatingPointError`` under ``np.errstate(all="raise")``)
        leaves the slices before it stepped and those after it not. What
        changes is the size of the step's temporaries, which grow with the
        worlds of a pass (those of the articulated contacts with the square
        of the contact points): the ragdoll under random torques on the
        ground peaks at about 0.3 MB per world of a pass after its fall
        (1.1 MB before the contact columns were packed), and at W = 1024 in
        one pass stepped about a fifth slower than in four of 256 (cache
        misses). A whole int, None or 0 (one pass).
    """

    dt: float = 1.0 / 60.0
    substeps: int = 4
    iterations: int = 1
    relax_iterations: int = 1
    free_contact_relax_passes: int = 1
    integrator: str = "symplectic"
    solver: str = "soft_step"
    joint_solver: str = "tree"
    joint_geometric_stiffness: bool = False
    joint_geometric_stiffness_cap: float = 1.0
    joint_limits_in_tree: bool | None = None
    joint_loops: str = "exact"
    joint_active_set_passes: int = 3
    joint_hertz: float = math.inf
    joint_damping_ratio: float = 2.0
    loop_joint_hertz: float = 120.0
    loop_joint_damping_ratio: float = 1.0
    free_joint_hertz: float = math.inf
    free_joint_geometric_stiffness: bool = True
    gs_joint_hertz: float = 60.0
    gs_joint_damping_ratio: float = 2.0
    joint_relax: bool = True
    joint_projection_passes: int = 8
    joint_projection_slop: float = 0.0002
    free_joint_projection_slop: float = 0.04
    joint_projection_contact_weight: float = 1000.0
    limit_hertz: float = math.inf
    limit_soft_margin: float = 0.05
    contact_coloring: str = "ordered"
    contact_hertz: float = 60.0
    articulated_contacts: bool | None = None
    articulated_contact_sweeps: int = 2
    contact_damping_ratio: float = 10.0
    contact_load_stiffening: float = 1.25
    joint_max_push_out: float = 3.0
    joint_max_angular_push_out: float = 10.0
    max_push_out: float = 3.0
    restitution_threshold: float = 1.0
    linear_slop: float = 0.0
    speculative_distance: float = 0.02
    static_contact_projection_depth: float = 0.02
    check_finite: bool = True
    world_chunk: int | None = 256

    def validate(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(f.default, str):
                if not isinstance(v, str):
                    raise ValueError(f"settings: {f.name} must be a string, got {v!r}")
                continue
            if v is None or isinstance(v, bool):
                continue
            if not isinstance(v, (int, float)) or math.isnan(v):
                raise ValueError(f"settings: {f.name} must be a number, got {v!r}")
        if not (self.dt > 0 and math.isfinite(self.dt)):
            raise ValueError(f"settings: dt must be a positive finite number of seconds, got {self.dt!r}")
        for name in ("substeps", "iterations", "joint_active_set_passes", "articulated_contact_sweeps"):
            v = getattr(self, name)
            if int(v) != v or v < 1:
                raise ValueError(f"settings: {name} must be an integer >= 1, got {v!r}")
        for name in ("relax_iterations", "free_contact_relax_passes", "joint_projection_passes"):
            v = getattr(self, name)
            if int(v) != v or v < 0:
                raise ValueError(f"settings: {name} must be an integer >= 0, got {v!r}")
        chunk = self.world_chunk
        if chunk is not None and (isinstance(chunk, bool) or not isinstance(chunk, numbers.Integral) or chunk < 0):
            raise ValueError(f"settings: world_chunk must be an integer >= 0 or None, got {chunk!r}")
        if self.integrator not in INTEGRATORS:
            raise ValueError(f"settings: unknown integrator {self.integrator!r}; choose one of {INTEGRATORS}")
        if self.solver not in SOLVERS:
            raise ValueError(f"settings: unknown solver {self.solver!r}; choose one of {SOLVERS}")
        if self.joint_solver not in JOINT_SOLVERS:
            raise ValueError(f"settings: unknown joint_solver {self.joint_solver!r}; choose one of {JOINT_SOLVERS}")
        if self.joint_loops not in JOINT_LOOPS:
            raise ValueError(f"settings: unknown joint_loops {self.joint_loops!r}; choose one of {JOINT_LOOPS}")
        if self.contact_coloring not in CONTACT_COLORINGS:
            raise ValueError(f"settings: unknown contact_coloring {self.contact_coloring!r}; "
                             f"choose one of {CONTACT_COLORINGS}")
        for name in ("joint_hertz", "loop_joint_hertz", "free_joint_hertz", "gs_joint_hertz", "contact_hertz",
                     "limit_hertz"):
            if not getattr(self, name) > 0:
                raise ValueError(f"settings: {name} must be > 0 (inf for rigid), got {getattr(self, name)!r}")
        for name in ("joint_limits_in_tree", "articulated_contacts"):
            if not (getattr(self, name) is None or isinstance(getattr(self, name), bool)):
                raise ValueError(f"settings: {name} must be True, False or None (on wherever it can act), got "
                                 f"{getattr(self, name)!r}")
            if getattr(self, name) and not self.tree_solve:
                # Both act through the joint tree, which only the soft-step solver's tree joint solver builds.
                raise ValueError(f"settings: {name} needs joint_solver 'tree' and solver 'soft_step', got "
                                 f"joint_solver {self.joint_solver!r} and solver {self.solver!r}")
        if self.joint_limits_in_tree and not math.isinf(self.limit_hertz):
            # The tree's active set solves rigid limit rows only; with soft limits the flag did nothing.
            raise ValueError(f"settings: joint_limits_in_tree solves rigid limits (limit_hertz inf), got limit_hertz "
                             f"{self.limit_hertz!r}; for soft limits leave joint_limits_in_tree off")
        for name in ("joint_geometric_stiffness_cap", "joint_damping_ratio", "loop_joint_damping_ratio",
                     "gs_joint_damping_ratio", "contact_damping_ratio", "max_push_out",
                     "joint_max_push_out", "joint_max_angular_push_out", "joint_projection_slop", "free_joint_projection_slop",
                     "joint_projection_contact_weight", "limit_soft_margin",
                     "restitution_threshold", "linear_slop", "speculative_distance"):
            v = getattr(self, name)
            if not (v >= 0 and math.isfinite(v)):
                raise ValueError(f"settings: {name} must be a finite number >= 0, got {v!r}")
        if not self.static_contact_projection_depth >= 0:
            raise ValueError(f"settings: static_contact_projection_depth must be a number >= 0 (inf: off), got "
                             f"{self.static_contact_projection_depth!r}")
        if not (self.contact_load_stiffening >= 1 and math.isfinite(self.contact_load_stiffening)):
            raise ValueError(f"settings: contact_load_stiffening must be a finite number >= 1 (1: off), got "
                             f"{self.contact_load_stiffening!r}")

    @property
    def tree_solve(self) -> bool:
        """Whether joints are solved by the soft step's tree solver (what the two flags below act through)."""
        return self.joint_solver == "tree" and self.solver == "soft_step"

    @property
    def limits_in_tree(self) -> bool:
        """``joint_limits_in_tree`` resolved: None (the default) is on wherever it can act (tree solve, rigid limits)."""
        if self.joint_limits_in_tree is None:
            return self.tree_solve and math.isinf(self.limit_hertz)
        return self.joint_limits_in_tree

    @property
    def contacts_articulated(self) -> bool:
        """``articulated_contacts`` resolved: None (the default) is on wherever it can act (tree solve)."""
        if self.articulated_contacts is None:
            return self.tree_solve
        return self.articulated_contacts

    @property
    def substep_dt(self) -> float:
        return self.dt / self.substeps
