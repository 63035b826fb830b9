import json
import math
import shutil
from pathlib import Path

import numba
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
    import torch
    from stable_baselines3 import PPO

    run = tmp_path / "resumed"
    shutil.copytree(tiny_run, run)
    before = PPO.load(str(run / "final_model.zip"), device="cpu").num_timesteps
    # the session's last checkpoint is its final model, after PPO's update on the last rollout
    # (SB3's CheckpointCallback saved one at that step count before the update), and the one
    # before it was taken after its rollout's update: Adam had made 8 steps (one rollout of 4 x 64
    # transitions in batches of 64, 2 epochs), not 0
    last, final = (PPO.load(str(p), device="cpu").policy for p in (common.checkpoints(run)[-1][1],
                                                                   run / "final_model.zip"))
    assert all(torch.equal(a, b) for a, b in zip(last.parameters(), final.parameters()))
    assert last.optimizer.state_dict()["state"][0]["step"] == final.optimizer.state_dict()["state"][0]["step"]
    assert [c[0] for c in common.checkpoints(run)] == [256, 512]
    first = PPO.load(str(common.checkpoints(run)[0][1]), device="cpu").policy
    assert int(first.optimizer.state_dict()["state"][0]["step"]) == 8
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


def test_residual_run_trains_and_evaluates_on_its_baseline(tmp_path, tiny_config):
    """A run whose config adds the policy to the LQR: the evaluation acts the
    same way, so a policy near zero keeps the pole up as the LQR does."""
    cfg = json.loads(tiny_config.read_text())
    cfg["residual"] = {"baseline": "lqr", "scale": 0.2}
    cfg["ppo"] = {**cfg["ppo"], "policy_kwargs": {"log_std_init": -3.0}}
    path = tmp_path / "residual.json"
    path.write_text(json.dumps(cfg))
    run = tmp_path / "residual"
    train.main([ENV, "--timesteps", "256", "--num-envs", "4", "--seed", "0", "--out", str(run),
                "--config", str(path), "--no-progress-bar"])
    assert json.loads((run / "config.json").read_text())["config"]["residual"]["baseline"] == "lqr"
    out = tmp_path / "eval.json"
    evaluate.main([str(run), "--episodes", "2", "--json", str(out), "--no-baselines",
                   "--video", str(tmp_path / "video")])
    res = json.loads(out.read_text())
    assert res["residual"] == {"baseline": "lqr", "scale": 0.2}
    assert res["fall_rate"] == 0.0 and res["mean_length"] == 50
    assert "video_error" not in res and len(res["videos"]) == 1  # the single env acts the same way


def test_policy_warmup_trains_the_critic_only(tmp_path, tiny_config):
    """Within ``policy_warmup_steps`` the actor of a residual run stays as
    built (zero action layer, initial log std) while the critic learns."""
    import torch
    from stable_baselines3 import PPO

    cfg = json.loads(tiny_config.read_text())
    cfg["residual"] = {"baseline": "lqr", "scale": 0.2}
    cfg["ppo"] = {**cfg["ppo"], "policy_kwargs": {"log_std_init": -3.0}}
    cfg["policy_warmup_steps"] = 512
    path = tmp_path / "warmup.json"
    path.write_text(json.dumps(cfg))
    run = tmp_path / "warmup"
    train.main([ENV, "--timesteps", "512", "--num-envs", "4", "--seed", "0", "--out", str(run),
                "--config", str(path), "--no-progress-bar"])
    policy = PPO.load(str(run / "final_model.zip"), device="cpu").policy
    first = PPO.load(str(common.checkpoints(run)[0][1]), device="cpu").policy
    assert all(torch.count_nonzero(p) == 0 for p in policy.action_net.parameters())
    assert torch.allclose(policy.log_std, torch.full_like(policy.log_std, -3.0))
    for a, b in zip(train.actor_parameters(policy), train.actor_parameters(first)):
        assert torch.equal(a, b)
    vf_final = torch.cat([p.flatten() for p in policy.value_net.parameters()])
    vf_first = torch.cat([p.flatten() for p in first.value_net.parameters()])
    assert not torch.equal(vf_final, vf_first)  # the critic was trained between the checkpoints

    path.write_text(json.dumps({**cfg, "policy_warmup_steps": -1}))
    with pytest.raises(SystemExit, match="policy_warmup_steps"):
        train.main([ENV, "--timesteps", "64", "--out", str(tmp_path / "x"), "--config", str(path),
                    "--no-progress-bar"])


def test_train_env_kwargs_change_the_training_env_only(tmp_path):
    """``train_env_kwargs`` (e.g. harder pushes) reach the training env; the
    evaluation env keeps ``env_kwargs``."""
    cfg = merge(get_config(ENV), {"env_kwargs": {"max_episode_steps": 50},
                                  "train_env_kwargs": {"max_episode_steps": 20}})
    venv, eval_env, _ = train._make_envs(ENV, cfg, 2, 0)
    try:
        assert venv.get_attr("max_episode_steps", [0]) == [20]
        assert eval_env.get_attr("max_episode_steps", [0]) == [50]
    finally:
        venv.close()
        eval_env.close()


def test_bad_residual_config_is_a_clear_error(tmp_path):
    path = tmp_path / "bad.json"
    path.write_text(json.dumps({"residual": {"baseline": "mpc"}}))
    with pytest.raises(SystemExit) as exc:
        train.main([ENV, "--timesteps", "64", "--out", str(tmp_path / "x"), "--config", str(path),
                    "--no-progress-bar"])
    assert "baseline must be one of" in str(exc.value.code)
    assert not (tmp_path / "x").exists()  # checked before the run directory is made


@pytest.fixture(scope="module")
def tiny_balance_run(tmp_path_factory):
    """A residual Balance run of 64 steps, 3 s episodes, a push every 0.5 s."""
    from ragdoll_env.tasks import BalanceTask

    step_s = BalanceTask.dt * BalanceTask.frame_skip
    cfg = {"env_kwargs": {"max_episode_steps": int(round(3.0 / step_s)), "push_interval": [0.5, 0.5]},
           "train_env_kwargs": None, "threads": 1,
           "ppo": {"n_steps": 32, "batch_size": 64, "n_epochs": 1},
           "eval": {"freq": 10_000, "episodes": 1, "num_envs": 1}, "checkpoint_freq": 10_000}
    tmp = tmp_path_factory.mktemp("balance")
    path = tmp / "bal.json"
    path.write_text(json.dumps(cfg))
    run = tmp / "bal"
    train.main(["Ragdoll/Balance-v0", "--timesteps", "64", "--num-envs", "2", "--seed", "0", "--out", str(run),
                "--config", str(path), "--no-progress-bar"])
    return run


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs 2 threads")
def test_physics_threads_train_the_same_run_bit_for_bit(tmp_path, monkeypatch, capsys):
    """--sim-threads 1 and 2 step the worlds of the training env (8, enough
    for the kernels' prange loops) and of the evaluation env on that many
    threads: the same model, normalisation and evaluations bit for bit. The
    count is the config's "threads", recorded in config.json; the evaluation
    tools step on the run's count unless told otherwise; --processes is a
    deprecated alias; a run recorded with "processes" still loads."""
    import pickle

    import torch
    from stable_baselines3 import PPO

    import ragdoll_env.batched as batched
    from ragdoll_env.tasks import BalanceTask

    made = []  # the threads of each env built (None: the engine's count)
    count = batched.thread_count

    def counted(threads, processes=None):
        made.append(count(threads, processes))
        return made[-1]

    monkeypatch.setattr(batched, "thread_count", counted)

    step_s = BalanceTask.dt * BalanceTask.frame_skip
    cfg = {"env_kwargs": {"max_episode_steps": round(1.0 / step_s), "push_interval": [0.5, 0.5]},
           "ppo": {"n_steps": 16, "batch_size": 64, "n_epochs": 1},
           "eval": {"freq": 128, "episodes": 2, "num_envs": 2}, "checkpoint_freq": 10_000}
    path = tmp_path / "bal.json"
    path.write_text(json.dumps(cfg))
    runs = {t: tmp_path / f"t{t}" for t in (1, 2)}
    for t, run in runs.items():
        train.main(["Ragdoll/Balance-v0", "--timesteps", "256", "--num-envs", "8", "--seed", "0",
                    "--out", str(run), "--config", str(path), "--no-progress-bar", "--sim-threads", str(t)])
        assert made == [t, t]  # the training env (8 worlds) and the evaluation env (2)
        made.clear()
        assert json.loads((run / "config.json").read_text())["config"]["threads"] == t
    # no --sim-threads: the config's (none: the engine's count); --processes N: --sim-threads min(N, cores)
    parser = train.build_parser()
    assert parser.parse_args(["Ragdoll/Balance-v0"]).sim_threads is None
    capsys.readouterr()
    assert parser.parse_args(["Ragdoll/Balance-v0", "--processes", "64"]).sim_threads == numba.config.NUMBA_NUM_THREADS
    assert "--processes is deprecated: the worlds step on threads; use --sim-threads" in capsys.readouterr().err
    one, two = runs[1], runs[2]
    a, b = (PPO.load(str(r / "final_model.zip"), device="cpu").policy for r in (one, two))
    assert all(torch.equal(x, y) for x, y in zip(a.parameters(), b.parameters()))
    n1, n2 = (pickle.loads((r / "vecnormalize.pkl").read_bytes()).obs_rms for r in (one, two))
    assert np.array_equal(n1.mean, n2.mean) and np.array_equal(n1.var, n2.var)
    with np.load(one / "eval" / "evaluations.npz") as e1, np.load(two / "eval" / "evaluations.npz") as e2:
        # 2 rollouts of 8 worlds x 16 steps, an evaluation every 128 // 8 = 16 steps of the 8 worlds
        assert e1["results"].shape == (2, 2)
        assert np.array_equal(e1["results"], e2["results"]) and np.array_equal(e1["ep_lengths"], e2["ep_lengths"])
    # training.evaluate steps on the run's threads unless told otherwise, with the same figures
    figures = {}
    for flags, want in (([], [2, 2, 2]), (["--sim-threads", "1"], [1, 1, 1])):  # the agent's env, two baselines'
        out = tmp_path / f"eval{len(flags)}.json"
        evaluate.main([str(two), "--episodes", "2", "--json", str(out)] + flags)
        assert made == want
        made.clear()
        figures[len(flags)] = {k: v for k, v in json.loads(out.read_text()).items() if "time" not in k}
    assert figures[0] == figures[2]
    # a run recorded before the threads: its "processes" is read as threads (at most the cores here)
    saved = json.loads((two / "config.json").read_text())
    del saved["config"]["threads"]
    saved["config"]["processes"] = 64
    (two / "config.json").write_text(json.dumps(saved))
    out = tmp_path / "eval_old.json"
    evaluate.main([str(two), "--episodes", "2", "--json", str(out)])
    assert made == [numba.config.NUMBA_NUM_THREADS] * 3
    made.clear()
    assert {k: v for k, v in json.loads(out.read_text()).items() if "time" not in k} == figures[0]
    saved["config"].pop("processes")
    saved["config"]["threads"] = None  # as the shipped configs record it: the engine's count
    (two / "config.json").write_text(json.dumps(saved))
    evaluate.main([str(two), "--episodes", "2", "--no-baselines", "--processes", "1"])
    assert made == [1]
    made.clear()
    evaluate.main([str(two), "--episodes", "2", "--no-baselines"])
    assert made == [None]
    made.clear()
    cores = numba.config.NUMBA_NUM_THREADS
    for bad, message in (({"threads": 0}, "threads .*must be a whole number >= 1"),
                         ({"threads": 1.5}, "threads .*must be a whole number >= 1"),
                         ({"threads": cores + 1}, f"threads .*must be at most {cores}"),
                         ({"processes": 0}, "processes .*must be a whole number >= 1"),
                         ({"processes": 1.5}, "processes .*must be a whole number >= 1"),
                         ({"processes": 2, "threads": 1}, "give threads only, not also processes"),
                         ({"env_kwargs": {"threads": 2}}, "threads goes at the top level"),
                         ({"env_kwargs": {"processes": 2}}, "processes goes at the top level"),
                         ({"train_env_kwargs": {"threads": 2}}, "threads goes at the top level")):
        path.write_text(json.dumps({**cfg, **bad}))
        with pytest.raises(SystemExit, match=message):
            train.main(["Ragdoll/Balance-v0", "--timesteps", "64", "--out", str(tmp_path / "x"), "--config",
                        str(path), "--no-progress-bar"])
        assert not (tmp_path / "x").exists()


def test_the_doc_configs_restore_the_runs_they_name():
    """docs/balance_pd_level.json over the default is the Balance entry before
    2026-12-06; docs/balance_push_trials.json the 32-world push-trial run's."""
    from training.configs import check_override, upgrade

    docs = Path(__file__).resolve().parents[2] / "docs"
    default = get_config("Ragdoll/Balance-v0")
    runs = {"balance_pd_level.json": {"num_envs": 32, "n_steps": 256, "lr": 3e-5, "scale": 0.1, "critic": 10,
                                      "train": None},
            "balance_push_trials.json": {"num_envs": 32, "n_steps": 256, "lr": 1e-4, "scale": 0.3, "critic": 3,
                                         "train": default["train_env_kwargs"]}}
    for name, want in runs.items():
        override = json.loads((docs / name).read_text())
        check_override(override)
        cfg = merge(default, upgrade(override))  # their "processes": 1, as recorded then, is one thread
        assert cfg["num_envs"] == want["num_envs"] and cfg["threads"] == 1 and "processes" not in cfg
        assert cfg["ppo"]["n_steps"] == want["n_steps"] and cfg["ppo"]["learning_rate"] == want["lr"]
        assert cfg["ppo"]["policy_kwargs"]["critic_lr_factor"] == want["critic"]
        assert cfg["residual"]["scale"] == want["scale"] and cfg["train_env_kwargs"] == want["train"]
    assert default["num_envs"] * default["ppo"]["n_steps"] == 32 * 256  # the same transitions per update


def test_push_sweep_rows_for_agent_and_baselines(tiny_balance_run, tmp_path):
    """A tiny residual Balance run: the sweep rolls the agent and the PD out
    at each strength, counting the pushes it gave."""
    from training import push_sweep

    from ragdoll_env.tasks import BalanceTask

    step_s = BalanceTask.dt * BalanceTask.frame_skip
    run = tiny_balance_run
    out, png = tmp_path / "sweep.json", tmp_path / "sweep.png"
    res = push_sweep.main([str(run), "--strengths", "0", "15", "--episodes", "2", "--baselines", "standing_pd",
                           "--json", str(out), "--plot", str(png)])
    assert json.loads(out.read_text())["rows"] == res["rows"] and png.stat().st_size > 1000
    assert [(r["strength"], r["controller"]) for r in res["rows"]] == [
        (0.0, "agent"), (0.0, "standing_pd"), (15.0, "agent"), (15.0, "standing_pd")]
    for r in res["rows"]:
        assert r["episodes"] == 2 and 0.0 <= r["fall_rate"] <= 1.0
        assert r["mean_length_s"] == pytest.approx(r["mean_length"] * step_s)
        if r["strength"] == 0:
            assert r["pushes"] == 0
        else:  # a push every 0.5 s: at least one before the 3 s limit or a fall
            assert r["pushes"] >= 2 and 0 <= r["pushes_survived"] <= r["pushes"]
    assert res["residual"]["baseline"] == "standing_pd"


def test_push_trials_survive_weak_pushes_and_fall_backwards(tiny_balance_run, tmp_path):
    """One push per world at the chest, towards the front and the back (on
    one thread and on all cores), for 3.5 s (beyond the run's 3 s episodes, which the
    trials do not truncate):
    at 5 N·s (the capture point moves 2 cm) nothing falls; at 25 N·s the PD
    takes the forward push on its toes and tips over its heels from the
    backward one (the centre of mass stands 2 cm behind the foot centres).
    The JSON holds the rows and the plot is written; a body that is not
    movable is named."""
    from training import push_trials

    out, png = tmp_path / "trials.json", tmp_path / "trials.png"
    res = push_trials.main([str(tiny_balance_run), "--strengths", "5", "25", "--directions", "2", "--bodies",
                            "chest", "--settle", "0.5", "--watch", "3", "--json", str(out), "--plot", str(png)])
    assert json.loads(out.read_text())["rows"] == res["rows"] and png.stat().st_size > 1000
    assert [(r["strength"], r["controller"], r["trials"]) for r in res["rows"]] == [
        (5.0, "agent", 2), (5.0, "standing_pd", 2), (25.0, "agent", 2), (25.0, "standing_pd", 2)]
    fell = {(r["strength"], r["controller"]): r["fell"]["chest"] for r in res["rows"]}
    assert fell[5.0, "agent"] == fell[5.0, "standing_pd"] == ".."
    assert fell[25.0, "standing_pd"] == ".X"
    assert all(r["falls_before_push"] == 0 for r in res["rows"])
    assert res["headings_deg"] == [0.0, 180.0]
    # the paired comparison counts the trials from the maps above
    pairs = [(x, y) for st in (5.0, 25.0) for x, y in zip(fell[st, "agent"], fell[st, "standing_pd"])]
    saved, lost = sum(p == (".", "X") for p in pairs), sum(p == ("X", ".") for p in pairs)
    assert res["comparisons"] == [{
        "baseline": "standing_pd", "trials": 4, "agent_falls": sum(x == "X" for x, _ in pairs),
        "baseline_falls": sum(y == "X" for _, y in pairs), "saved": saved, "lost": lost,
        "sign_test_p": push_trials.sign_test_p(saved, lost)}]
    # the same trials with each env's 2 worlds on all cores (the run's config says 1 thread)
    two = push_trials.main([str(tiny_balance_run), "--strengths", "5", "25", "--directions", "2", "--bodies",
                            "chest", "--settle", "0.5", "--watch", "3", "--sim-threads",
                            str(numba.config.NUMBA_NUM_THREADS)])
    assert two["rows"] == res["rows"]
    with pytest.raises(SystemExit, match="no body named 'nose'"):
        push_trials.main([str(tiny_balance_run), "--strengths", "5", "--directions", "1", "--bodies", "nose"])


def test_sign_test_p_is_the_exact_binomial_tail():
    """Two-sided exact sign test: n discordant pairs split k / n - k under a
    fair coin: 2 P(X <= min(k, n - k)), capped at 1."""
    from training.push_trials import sign_test_p

    assert sign_test_p(0, 0) == 1.0 and sign_test_p(3, 3) == 1.0
    assert sign_test_p(5, 0) == sign_test_p(0, 5) == 2 / 32
    assert sign_test_p(1, 9) == 2 * 11 / 1024
    assert math.isclose(sign_test_p(19, 5), 2 * sum(math.comb(24, i) for i in range(6)) / 2 ** 24)
    assert sign_test_p(19, 5) < 0.01 < sign_test_p(17, 9) < sign_test_p(14, 12) <= 1.0
    # thousands of pairs: exact integers, no float overflow
    assert sign_test_p(600, 500) < 0.01 and sign_test_p(1500, 1500) == 1.0


def test_push_trial_comparison_counts_each_trial_against_each_baseline():
    """compare() over hand-written rows: two strengths, two bodies, two
    baselines; saved = the baseline fell where the agent stood."""
    from training.push_trials import compare, sign_test_p

    def row(strength, controller, chest, pelvis):
        fell = {"chest": chest, "pelvis": pelvis}
        return {"strength": strength, "controller": controller, "trials": 8,
                "falls": sum(m.count("X") for m in fell.values()), "fell": fell}

    rows = [row(20.0, "agent", "..X.", "...."), row(20.0, "pd", "XXX.", "...."), row(20.0, "zero", "XXXX", "XXXX"),
            row(25.0, "agent", "X..X", ".X.."), row(25.0, "pd", "X...", "XX.X"), row(25.0, "zero", "XXXX", "XXXX")]
    # against pd: 20 N·s saved 2 (chest 0, 1); 25 N·s saved 2 (pelvis 0, 3), lost 1 (chest 3)
    assert compare(rows, "pd") == {"baseline": "pd", "trials": 16, "agent_falls": 4, "baseline_falls": 7,
                                   "saved": 4, "lost": 1, "sign_test_p": sign_test_p(4, 1)}
    assert compare(rows, "zero") == {"baseline": "zero", "trials": 16, "agent_falls": 4, "baseline_falls": 16,
                                     "saved": 12, "lost": 0, "sign_test_p": sign_test_p(12, 0)}


def test_model_option_picks_best_final_or_last(tiny_run, tmp_path):
    """--model best (the default), final, last or a checkpoint's timesteps:
    the evaluation names the model it loaded; a run without the one asked
    for is a clear error, naming the checkpoints it has."""
    from training import common

    first = common.checkpoints(tiny_run)[0][0]
    labels = {which: evaluate.main([str(tiny_run), "--episodes", "1", "--num-envs", "1", "--no-baselines",
                                    "--model", which])["model"] for which in ("best", "final", "last", str(first))}
    last = common.last_checkpoint(tiny_run)[0]
    assert labels == {"best": "best_model", "final": "final_model", "last": f"checkpoint_{last}",
                      str(first): f"checkpoint_{first}"}
    with pytest.raises(SystemExit, match=f"no checkpoint at {first + 1} timesteps; it has \\[{first}"):
        evaluate.main([str(tiny_run), "--episodes", "1", "--model", str(first + 1)])
    with pytest.raises(SystemExit) as exc:
        evaluate.main([str(tiny_run), "--model", "worst"])
    assert exc.value.code == 2  # argparse names the choices
    bare = tmp_path / "bare"
    bare.mkdir()
    for name in ("config.json", "best_model.zip", "best_vecnormalize.pkl"):
        (bare / name).write_bytes((tiny_run / name).read_bytes())
    with pytest.raises(SystemExit, match="holds no model \\(final_model.zip\\)"):
        evaluate.main([str(bare), "--episodes", "1", "--model", "final"])


def test_eval_env_kwargs_change_the_evaluation_env_only(tiny_run, tiny_config, tmp_path):
    """eval.env_kwargs is merged over env_kwargs for the training's
    evaluation env alone: 3-step evaluation episodes here, while the
    training env keeps the config's 50 steps (and the evaluations of the
    run without it last longer than 3)."""
    import csv

    cfg = json.loads(tiny_config.read_text())
    cfg["eval"]["env_kwargs"] = {"max_episode_steps": 3}
    path = tmp_path / "short_eval.json"
    path.write_text(json.dumps(cfg))
    run = tmp_path / "short"
    train.main([ENV, "--timesteps", "512", "--num-envs", "4", "--seed", "3", "--out", str(run), "--config", str(path),
                "--no-progress-bar"])
    with np.load(run / "eval" / "evaluations.npz") as short, np.load(tiny_run / "eval" / "evaluations.npz") as full:
        assert short["ep_lengths"].max() == 3 and full["ep_lengths"].max() > 3
    with open(run / "train_0.monitor.csv") as f:
        lengths = [int(r["l"]) for r in csv.DictReader(line for line in f if not line.startswith("#"))]
    assert max(lengths) > 3  # the training env's episodes are not cut at 3


def test_push_sweep_and_trials_need_a_balance_run(tiny_run):
    from training import push_sweep, push_trials

    with pytest.raises(SystemExit, match="pushes need a Ragdoll/Balance-v0 run"):
        push_sweep.main([str(tiny_run), "--episodes", "1"])
    with pytest.raises(SystemExit, match="pushes need a Ragdoll/Balance-v0 run"):
        push_trials.main([str(tiny_run), "--directions", "1"])
    with pytest.raises(SystemExit, match="--watch > 0"):
        push_trials.main([str(tiny_run), "--watch", "0"])


def test_a_run_records_its_engine_settings_and_evaluation_names_the_changed_ones(tiny_run, tmp_path):
    """config.json keeps the engine settings the run was trained with; an
    evaluation in an engine that steps otherwise warns and reports each
    changed field with its trained and current values."""
    import engine

    saved = json.loads((tiny_run / "config.json").read_text())
    recorded = saved["engine_settings"]
    assert recorded["joint_projection_slop"] == engine.Settings().joint_projection_slop
    assert "world_chunk" not in recorded  # it never changes a trajectory
    out = tmp_path / "same.json"
    evaluate.main([str(tiny_run), "--episodes", "1", "--no-baselines", "--json", str(out)])
    assert json.loads(out.read_text())["engine_settings_changed"] == {}

    run = tmp_path / "older"
    shutil.copytree(tiny_run, run)
    saved["engine_settings"] = {**recorded, "joint_projection_slop": 0.005}
    (run / "config.json").write_text(json.dumps(saved))
    out = tmp_path / "changed.json"
    with pytest.warns(UserWarning, match="joint_projection_slop"):
        evaluate.main([str(run), "--episodes", "1", "--no-baselines", "--json", str(out)])
    changed = json.loads(out.read_text())["engine_settings_changed"]
    assert changed == {"joint_projection_slop": [0.005, recorded["joint_projection_slop"]]}


def test_a_setting_added_since_a_run_counts_as_its_old_behaviour():
    """A field the run did not record is compared as the value that steps as
    the engine did before it (``ADDED_SETTINGS``); an unknown one as None."""
    C = common
    current = {"joint_projection_slop": 0.0002, "static_contact_projection_depth": math.inf}
    assert C.settings_changes({"joint_projection_slop": 0.0002}, current) == {}
    on = {**current, "static_contact_projection_depth": 0.02}
    assert C.settings_changes({"joint_projection_slop": 0.0002}, on) == {
        "static_contact_projection_depth": (math.inf, 0.02)}
    assert C.settings_changes({"joint_projection_slop": 0.0002}, {**current, "new_field": 1.0}) == {
        "new_field": (None, 1.0)}


def test_a_residual_baseline_argument_added_since_a_run_reads_as_trained(tmp_path):
    """A Balance run whose residual did not record ``lifted_ankle`` (trained
    before 2026-12-05) is read back on the PD it was trained on (1.0, the
    full gains); a recorded value is kept; the baseline row beside a run is
    the PD its residual is built on."""
    from training.configs import CONFIGS

    C = common
    run = tmp_path / "old"
    run.mkdir()
    old = {"baseline": "standing_pd", "scale": 0.1}
    saved = {"env_id": "Ragdoll/Balance-v0", "config": {"residual": old}}
    (run / "config.json").write_text(json.dumps(saved))
    read = C.read_run_config(run)["config"]["residual"]
    assert read == {**old, "kwargs": {"lifted_ankle": 1.0}}
    assert C.residual_as_trained({**old, "kwargs": {"lifted_ankle": 0.25}}, "Ragdoll/Balance-v0")["kwargs"] == {
        "lifted_ankle": 0.25}
    assert C.residual_as_trained({"baseline": "pd", "scale": 1.0}, "Ragdoll/Balance-v0")["kwargs"] == {
        "lifted_ankle": 1.0}
    assert C.residual_as_trained({"baseline": "lqr", "scale": 1.0}, "Ragdoll/InvertedPendulum-v0") == {
        "baseline": "lqr", "scale": 1.0}
    assert C.residual_as_trained(None, "Ragdoll/Balance-v0") is None
    balance = "Ragdoll/Balance-v0"
    assert C.baseline_kwargs("standing_pd", read, balance) == {"lifted_ankle": 1.0}
    assert C.baseline_kwargs("zero", read, balance) == {}
    assert C.baseline_kwargs("standing_pd", {"baseline": "pd", "kwargs": {"lifted_ankle": 1.0}}, balance) == {
        "lifted_ankle": 1.0}
    # New runs record the value they train with.
    assert CONFIGS["Ragdoll/Balance-v0"]["residual"]["kwargs"] == {"lifted_ankle": 0.25}


def test_run_files_are_strict_json_and_read_back(tiny_run):
    # Other languages' parsers reject Infinity and NaN: the run files spell an
    # infinite setting "inf", and the tools read it back as the float.
    def reject(constant):
        raise ValueError(f"non-standard JSON constant {constant}")

    for path in tiny_run.glob("*.json"):
        json.loads(path.read_text(), parse_constant=reject)
    written = json.loads((tiny_run / common.CONFIG_FILE).read_text())["engine_settings"]
    infinite = [k for k, v in written.items() if v == "inf"]
    assert infinite  # joint_hertz among them at the defaults
    recorded = common.read_run_config(tiny_run)["engine_settings"]
    current = {k: common.float_from_json(v) for k, v in written.items()}
    assert all(recorded[k] == current[k] == math.inf for k in infinite)
    assert common.settings_changes(recorded, current) == {}
    assert common.settings_changes(recorded, {**current, infinite[0]: 60.0}) == {infinite[0]: (math.inf, 60.0)}


def test_an_infinite_env_kwarg_reads_back_as_the_float(tmp_path):
    # A config with an infinite value (e.g. static_contact_projection_depth
    # inf, the engine before 2026-12-05) is written as "inf" and must reach
    # the env as the float again when a tool reads the run.
    common.write_json(tmp_path / common.CONFIG_FILE, {
        "env_id": ENV, "config": {"env_kwargs": {"static_contact_projection_depth": math.inf}},
        "engine_settings": {"joint_hertz": math.inf, "dt": 0.04}})
    saved = common.read_run_config(tmp_path)
    assert saved["config"]["env_kwargs"]["static_contact_projection_depth"] == math.inf
    assert saved["engine_settings"] == {"joint_hertz": math.inf, "dt": 0.04}
    from ragdoll_env.sb3 import make_sb3_vec_env
    venv = make_sb3_vec_env(ENV, 1, **saved["config"]["env_kwargs"])
    try:
        assert venv.core.settings.static_contact_projection_depth == math.inf
    finally:
        venv.close()
