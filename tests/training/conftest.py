import json

import pytest

pytest.importorskip("stable_baselines3")
pytest.importorskip("torch")

ENV = "Ragdoll/InvertedPendulum-v0"

#: a tiny, fast configuration: 50-step episodes, 2 rollouts of 4 x 64 steps, evaluations every 256 steps
TINY = {
    "env_kwargs": {"max_episode_steps": 50},
    "ppo": {"n_steps": 64, "batch_size": 64, "n_epochs": 2},
    "eval": {"freq": 256, "episodes": 2, "num_envs": 2},
    "checkpoint_freq": 256,
}


@pytest.fixture(scope="session")
def tiny_config(tmp_path_factory):
    path = tmp_path_factory.mktemp("cfg") / "tiny.json"
    path.write_text(json.dumps(TINY))
    return path


@pytest.fixture(scope="session")
def tiny_run(tmp_path_factory, tiny_config):
    from training import train

    run = tmp_path_factory.mktemp("runs") / "ip"
    train.main([ENV, "--timesteps", "512", "--num-envs", "4", "--seed", "3", "--out", str(run),
                "--config", str(tiny_config), "--no-progress-bar"])
    return run
