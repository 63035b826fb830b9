import json
import shutil

import numpy as np
import pytest

from training import common, evaluate, plot, train
from training.configs import CONFIGS, get_config, merge

ENV = "Ragdoll/InvertedPendulum-v0"

KEYS = ("episodes", "mean_return", "std_return", "mean_length", "fall_rate")


def test_configs_cover_every_env():
    import ragdoll_env

    assert set(CONFIGS) == set(ragdoll_env.ENV_IDS)
    cfg = merge(get_config(ENV), {"ppo": {"learning_rate": 5e-4}})
    assert cfg["ppo"]["learning_rate"] == 5e-4 and cfg["ppo"]["batch_size"] == CONFIGS[ENV]["ppo"]["batch_size"]
    assert CONFIGS[ENV]["ppo"]["learning_rate"] != 5e-4  # merge copies


def test_tiny_run_writes_model_summary_and_evaluates(tiny_run, tmp_path):
    for name in ("config.json", "summary.json", "final_model.zip", "vecnormalize.pkl", "best_model.zip",
                 "best_vecnormalize.pkl", "eval/evaluations.npz"):
        assert (tiny_run / name).is_file(), name
    assert common.checkpoints(tiny_run)[-1][0] == 512
    assert any((tiny_run / "tb").rglob("events.out.tfevents*"))
    summary = json.loads((tiny_run / "summary.json").read_text())
    assert summary["env_id"] == ENV and summary["seed"] == 3 and summary["num_timesteps"] == 512
    assert {"python", "numpy", "torch", "stable_baselines3", "gymnasium", "ragdoll"} <= set(summary["versions"])
    assert summary["wall_time_s"] > 0
    assert len(summary["evaluations"]["timesteps"]) == 2
    assert summary["config"]["ppo"]["n_steps"] == 64

    out = tmp_path / "eval.json"
    evaluate.main([str(tiny_run), "--episodes", "2", "--json", str(out)])
    res = json.loads(out.read_text())
    assert res["deterministic"] is True  # the mean action by default, as SB3's evaluate_policy
    for key in KEYS:
        assert key in res, key
    assert res["episodes"] == 2 and res["model"] == "best_model"
    assert set(res["baselines"]) == {"zero", "pendulum_pd", "lqr"}
    for name, b in res["baselines"].items():
        for key in KEYS:
            assert key in b, (name, key)
    assert res["baselines"]["zero"]["fall_rate"] == 1.0  # the unpowered pole falls
    assert res["baselines"]["lqr"]["fall_rate"] == 0.0

    png = plot.plot(tiny_run, tmp_path / "curve.png")
    assert png.stat().st_size > 1000


def test_resume_continues_the_step_count(tiny_run, tmp_path, tiny_config):
    from stable_baselines3 import PPO

    run = tmp_path / "resumed"
    shutil.copytree(tiny_run, run)
    before = PPO.load(str(run / "final_model.zip"), device="cpu").num_timesteps
    summary = train.main(["--resume", str(run), "--timesteps", "1024", "--no-progress-bar"])
    assert before == 512
    assert summary["num_timesteps"] == 1024 > before
    assert common.checkpoints(run)[-1][0] == 1024
    assert PPO.load(str(run / "final_model.zip"), device="cpu").num_timesteps == 1024
    assert [s["start_timesteps"] for s in summary["sessions"]] == [0, 512]
    with np.load(run / "eval" / "evaluations.npz") as data:  # earlier evaluations kept
        assert list(data["timesteps"]) == [256, 512, 768, 1024]


def test_bad_env_id_is_named_with_the_known_ids(tmp_path):
    with pytest.raises(SystemExit) as exc:
        train.main(["Ragdoll/Nope-v0", "--out", str(tmp_path / "x"), "--no-progress-bar"])
    msg = str(exc.value.code)
    assert "Ragdoll/Nope-v0" in msg and ENV in msg and "Ragdoll/Balance-v0" in msg
    with pytest.raises(ValueError, match="unknown environment id"):
        common.resolve_env_id("CartPole-v1")
    assert common.resolve_env_id("InvertedPendulum-v0") == ENV
    assert not (tmp_path / "x").exists()


def test_missing_run_dir_is_a_clear_error(tmp_path):
    missing = str(tmp_path / "nowhere")
    with pytest.raises(SystemExit) as exc:
        evaluate.main([missing])
    assert "does not exist" in str(exc.value.code) and missing in str(exc.value.code)
    with pytest.raises(SystemExit) as exc:
        train.main(["--resume", missing])
    assert "does not exist" in str(exc.value.code)
    with pytest.raises(SystemExit) as exc:
        plot.main([missing])
    assert "does not exist" in str(exc.value.code)


def test_existing_run_dir_is_not_overwritten(tiny_run):
    with pytest.raises(SystemExit, match="--resume"):
        train.main([ENV, "--out", str(tiny_run), "--no-progress-bar"])


def test_corrupted_checkpoint_is_a_clear_error(tiny_run, tmp_path):
    run = tmp_path / "broken"
    shutil.copytree(tiny_run, run)
    _, model, _ = common.checkpoints(run)[-1]
    model.write_bytes(b"this is not a zip file")
    with pytest.raises(SystemExit) as exc:
        train.main(["--resume", str(run), "--timesteps", "1024", "--no-progress-bar"])
    msg = str(exc.value.code)
    assert "corrupted" in msg and str(model) in msg
    (run / "best_model.zip").write_bytes(b"\x00" * 100)
    with pytest.raises(SystemExit, match="corrupted"):
        evaluate.main([str(run), "--episodes", "1"])
    (run / "vecnormalize.pkl").write_bytes(b"garbage")
    with pytest.raises(common.TrainingError, match="corrupted"):
        common.load_vecnormalize(run / "vecnormalize.pkl", None)
