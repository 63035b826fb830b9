"""The policy whose critic steps at its own learning rate (training.policies)."""

import json

import numpy as np
import pytest

from training import common, train

ENV = "Ragdoll/InvertedPendulum-v0"


def _first_step(factor, lr=1e-3):
    """A CriticRatePolicy PPO on the tiny pendulum after one Adam step on
    one batch: (policy, actor and critic parameters before the step)."""
    import torch
    from stable_baselines3 import PPO

    from ragdoll_env.sb3 import make_sb3_vec_env
    from training.policies import CriticRatePolicy

    venv = make_sb3_vec_env(ENV, num_envs=2, seed=0, max_episode_steps=50)
    try:
        model = PPO(CriticRatePolicy, venv, n_steps=32, batch_size=64, n_epochs=1, learning_rate=lr, seed=0,
                    device="cpu", policy_kwargs={"critic_lr_factor": factor, "net_arch": {"pi": [8], "vf": [8]},
                                                 "optimizer_kwargs": {"eps": 1e-16}})
        policy = model.policy
        actor = [p.detach().clone() for p in train.actor_parameters(policy)]
        critic = [p.detach().clone() for p in policy.critic_parameters()]
        model.learn(64)  # one rollout of 2 x 32 steps, one batch, one optimizer step
    finally:
        venv.close()
    return policy, actor, critic, torch


@pytest.mark.parametrize("factor", [1.0, 10.0])
def test_the_critic_steps_at_its_factor_times_the_learning_rate(factor):
    """Adam's first step moves each parameter with a gradient by its group's
    learning rate (m̂/(√v̂ + ε) = g/(|g| + ε) = ±1, with ε 1e-16 here: some
    gradients are below the default 1e-8): the actor's by lr, the critic's
    by factor × lr."""
    lr = 1e-3
    policy, actor, critic, torch = _first_step(factor, lr)
    # the two groups are the actor's and the critic's parameters, all of them, each once
    by_name = dict(policy.named_parameters())
    critic_names = {n for n in by_name if n.startswith(("mlp_extractor.value_net.", "value_net."))}
    groups = [{id(p) for p in g["params"]} for g in policy.optimizer.param_groups]
    assert groups[1] == {id(by_name[n]) for n in critic_names}
    assert groups[0] == {id(p) for n, p in by_name.items() if n not in critic_names}
    for before, now, rate in ((actor, train.actor_parameters(policy), lr),
                              (critic, policy.critic_parameters(), factor * lr)):
        step = torch.cat([(p.detach() - q).abs().flatten() for p, q in zip(now, before)]).numpy()
        moved = step[step > 0]
        assert moved.size > 0.5 * step.size
        np.testing.assert_allclose(moved, rate, rtol=1e-3)
    assert [g["lr"] for g in policy.optimizer.param_groups] == [lr, lr]  # read as the schedule's, as SB3 logs it


def test_a_run_with_a_critic_rate_resumes_with_its_optimizer_groups(tmp_path, tiny_config):
    """``critic_lr_factor`` in policy_kwargs trains the CriticRatePolicy; the
    saved model reloads (as ``--resume`` and evaluation load it) with the
    same factor, the same two groups and Adam's state in both."""
    from stable_baselines3 import PPO

    from training.policies import CriticRatePolicy

    cfg = json.loads(tiny_config.read_text())
    cfg["ppo"] = {**cfg["ppo"], "policy_kwargs": {"critic_lr_factor": 4.0}}
    path = tmp_path / "critic.json"
    path.write_text(json.dumps(cfg))
    run = tmp_path / "critic"
    train.main([ENV, "--timesteps", "256", "--num-envs", "4", "--seed", "0", "--out", str(run),
                "--config", str(path), "--no-progress-bar"])
    train.main(["--resume", str(run), "--timesteps", "512", "--no-progress-bar"])
    model = PPO.load(str(run / "final_model.zip"), device="cpu")
    assert model.num_timesteps == 512
    assert isinstance(model.policy, CriticRatePolicy) and model.policy.critic_lr_factor == 4.0
    groups = model.policy.optimizer.param_groups
    assert [g["lr_factor"] for g in groups] == [1.0, 4.0]
    state = model.policy.optimizer.state_dict()["state"]
    assert len(state) == sum(len(g["params"]) for g in groups)  # every parameter has its Adam moments
    # 8 Adam steps a rollout (256 transitions, batches of 64, 2 epochs), one rollout a session:
    # the resumed session continued the first one's moments
    assert {int(s["step"]) for s in state.values()} == {16}

    path.write_text(json.dumps({"ppo": {"policy_kwargs": {"critic_lr_factor": 2.0}}}))
    with pytest.raises(SystemExit, match="policy_kwargs cannot change"):
        train.main(["--resume", str(run), "--timesteps", "768", "--config", str(path), "--no-progress-bar"])


@pytest.mark.parametrize("factor", [0.0, -1.0, float("inf"), float("nan"), "ten"])
def test_a_bad_critic_rate_is_refused(factor):
    with pytest.raises(ValueError, match="critic_lr_factor"):
        _first_step(factor)


def test_a_critic_rate_needs_the_mlp_policy_and_null_is_none():
    from training.policies import CriticRatePolicy

    with pytest.raises(common.TrainingError, match="critic_lr_factor.*CnnPolicy"):
        common.ppo_arguments({"policy": "CnnPolicy", "policy_kwargs": {"critic_lr_factor": 10.0}})
    assert common.ppo_arguments({"policy_kwargs": {"critic_lr_factor": 10.0}})[0] is CriticRatePolicy
    # a --config with a null factor gives SB3's own MlpPolicy, one Adam rate (Balance before 2026-12-05 evening)
    policy, kwargs = common.ppo_arguments({"n_steps": 8, "policy_kwargs": {"critic_lr_factor": None}})
    assert policy == "MlpPolicy" and kwargs == {"n_steps": 8, "policy_kwargs": {}}
