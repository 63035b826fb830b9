"""Gymnasium environments on the ragdoll engine.

Importing this package registers, under the namespace ``Ragdoll``:

=====================================  ===========================================================
``Ragdoll/InvertedPendulum-v0``        one pole on a torque-limited hinge, 1000 steps of 0.04 s
``Ragdoll/InvertedDoublePendulum-v0``  two links (ankle and hip), torques at both, 1000 steps
``Ragdoll/Balance-v0``                 the humanoid standing on the ground through random pushes,
                                       1200 steps of 1/60 s (20 s)
=====================================  ===========================================================

each with an ``entry_point`` (:mod:`ragdoll_env.single`) and a native batched
``vector_entry_point`` (:mod:`ragdoll_env.vector`)::

    import gymnasium as gym
    env = gym.make("ragdoll_env:Ragdoll/Balance-v0", push_strength=(10, 30))
    envs = gym.make_vec("Ragdoll/Balance-v0", num_envs=64, vectorization_mode="vector_entry_point")
    from ragdoll_env.sb3 import make_sb3_vec_env      # SB3 VecEnv on the same batched core
    venv = make_sb3_vec_env("Ragdoll/InvertedPendulum-v0", num_envs=16)

Baseline controllers are in :mod:`ragdoll_env.baselines`, the passive ragdoll
demo in ``python -m ragdoll_env.demo``.
"""

from __future__ import annotations

from gymnasium.envs.registration import register, registry

from .tasks import BalanceTask, InvertedDoublePendulumTask, InvertedPendulumTask

ENV_IDS = (InvertedPendulumTask.env_id, InvertedDoublePendulumTask.env_id, BalanceTask.env_id)

_ENTRY = {
    InvertedPendulumTask.env_id: "InvertedPendulum",
    InvertedDoublePendulumTask.env_id: "InvertedDoublePendulum",
    BalanceTask.env_id: "Balance",
}


def _register():
    for task in (InvertedPendulumTask, InvertedDoublePendulumTask, BalanceTask):
        if task.env_id in registry:
            continue
        name = _ENTRY[task.env_id]
        register(
            id=task.env_id,
            entry_point=f"ragdoll_env.single:{name}Env",
            vector_entry_point=f"ragdoll_env.vector:{name}VectorEnv",
            max_episode_steps=task.max_episode_steps,
        )


_register()

__all__ = ["ENV_IDS"]
