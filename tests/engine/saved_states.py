"""States saved from runs of random maximum torques on the standing ragdoll
(``benchmarks.scenes.ragdoll_max_torque``, seed 0: ``soak_*`` from the slow
soak's 1,000 worlds, ``tests/stability/test_soak.py``; ``maxtorque16_*`` from
16 worlds) just before a step that once went wrong, with the motor torques of
that step, so that a fast test replays that step instead of the run."""

from __future__ import annotations

from pathlib import Path

import numpy as np

DATA = Path(__file__).parent / "data"


def saved_soak_world(name, **settings):
    """(model, state, motor (steps, 1, actuators) N·m) of ``data/NAME.npz``, the
    model ``benchmarks.scenes.ragdoll_max_torque``'s with ``settings``."""
    from benchmarks import scenes as sc

    data = np.load(DATA / f"{name}.npz")
    model = sc.ragdoll_max_torque(num_worlds=1, seed=0).model.with_settings(**settings)
    state = model.initial_state(1)
    for k in state.arrays:
        state.arrays[k][...] = data[k]
    return model, state, data["motor"]
