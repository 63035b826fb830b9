"""User-facing robustness of ``training.train`` and the other CLIs: failed
starts leave no run behind, Ctrl-C saves a resumable checkpoint, 0 and
negative counts are argparse errors (0 turns evaluations/checkpoints off),
unknown config keys are named, summary.json lists existing files only, and
a resume with nothing to do changes nothing."""

import json
import os
import pickle
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from training import common, evaluate, plot, push_sweep, push_trials, train
from training.configs import CONFIGS, KEYS, check_override

ENV = "Ragdoll/InvertedPendulum-v0"
REPO = Path(__file__).resolve().parents[2]

#: with conftest's TINY config: rollouts of 2 x 64 steps
SMALL = ["--num-envs", "2", "--seed", "0", "--no-progress-bar"]


def _config(tmp_path, name, data) -> str:
    path = tmp_path / f"{name}.json"
    path.write_text(json.dumps(data))
    return str(path)


@pytest.fixture
def tiny(tiny_config, tmp_path):
    """``tiny(**changes)``: the path of conftest's TINY config with top-level entries changed."""
    return lambda **changes: _tiny(tmp_path, json.loads(tiny_config.read_text()), **changes)


def _tiny(tmp_path, cfg, **changes) -> str:
    for key, value in changes.items():
        cfg[key] = {**cfg[key], **value} if isinstance(value, dict) and isinstance(cfg.get(key), dict) else value
    return _config(tmp_path, "tiny_" + "_".join(changes), cfg)


# -- 1: a run that fails before its first step blocks nothing ------------------------------------------------------

@pytest.mark.parametrize("bad, message", [
    ({"ppo": {"policy_kwargs": {"activation_fn": "gelu"}}}, "unknown activation_fn 'gelu'"),
    ({"env_kwargs": {"bogus": 1}}, "unknown keyword argument 'bogus'"),
    ({"residual": {"baseline": "lqr", "actuators": ["nope"]}}, "actuator part 'nope'"),
    ({"eval": {"num_envs": 0}}, "eval.num_envs must be a whole number >= 1, got 0"),
    ({"ppo": {"batch_size": "many"}}, "bad PPO settings"),
    ({"normalize": {"bogus": 1}}, "bad normalize settings"),
    ({"eval": {"freq": 64, "episodes": 1, "num_envs": 1, "env_kwargs": {"bogus": 1}}},
     "unknown keyword argument 'bogus'"),
    ({"eval": {"env_kwargs": [1]}}, "'eval.env_kwargs' must be a mapping or null"),
    ({"eval": {"env_kwargs": {"threads": 2}}}, "threads goes at the top level of the config, not in 'eval.env_kwargs'"),
    ({"eval": {"env_kwargs": {"processes": 2}}}, "processes goes at the top level of the config, not in 'eval.env_kwargs'"),
    ({"threads": 0}, "threads (physics threads per env) must be a whole number >= 1, got 0"),
    ({"threads": "2"}, "threads (physics threads per env) must be a whole number >= 1, got '2'"),
    ({"processes": True}, "processes (deprecated: threads) must be a whole number >= 1, got True"),
])
def test_failed_start_writes_nothing(tmp_path, bad, message):
    run = tmp_path / "run"
    with pytest.raises(SystemExit) as exc:
        train.main([ENV, "--timesteps", "128", "--out", str(run), "--config", _config(tmp_path, "bad", bad), *SMALL])
    assert message in str(exc.value.code)
    assert not run.exists()  # nothing that a rerun would take for a run


def test_config_without_a_model_does_not_block_a_fresh_start(tmp_path, tiny, capsys):
    """A directory holding only the config.json of a failed start (as earlier
    versions left) is started afresh; --resume says there is nothing to
    resume and how to start it; a bad --config given with --resume leaves
    the run's config.json as it was."""
    run = tmp_path / "run"
    with pytest.raises(SystemExit, match="unknown activation_fn"):
        train.main([ENV, "--timesteps", "128", "--out", str(run), *SMALL,
                    "--config", _config(tmp_path, "bad", {"ppo": {"policy_kwargs": {"activation_fn": "gelu"}}})])
    run.mkdir()
    (run / "config.json").write_text(json.dumps({"env_id": ENV, "seed": 0, "num_envs": 2, "timesteps": 128,
                                                 "config": {"ppo": {"policy_kwargs": {"activation_fn": "gelu"}}},
                                                 "sessions": []}))
    with pytest.raises(SystemExit) as exc:
        train.main(["--resume", str(run), *SMALL])
    assert "no checkpoint" in str(exc.value.code) and f"--out {run}" in str(exc.value.code)

    summary = train.main([ENV, "--timesteps", "128", "--out", str(run), "--config", tiny(), *SMALL])
    assert "starting afresh" in capsys.readouterr().out
    assert summary["num_timesteps"] == 128 and common.checkpoints(run)[-1][0] == 128
    assert json.loads((run / "config.json").read_text())["config"]["ppo"]["policy_kwargs"] == {
        "net_arch": {"pi": [64, 64], "vf": [64, 64]}, "activation_fn": "tanh"}

    before = (run / "config.json").read_bytes()
    with pytest.raises(SystemExit, match="unknown activation_fn"):
        train.main(["--resume", str(run), "--timesteps", "256", *SMALL,
                    "--config", _config(tmp_path, "bad2", {"ppo": {"policy_kwargs": {"activation_fn": "gelu"}}})])
    assert (run / "config.json").read_bytes() == before
    with pytest.raises(SystemExit, match="already holds a run"):  # a run with a model is never overwritten
        train.main([ENV, "--timesteps", "128", "--out", str(run), *SMALL])


# -- 2: Ctrl-C saves a checkpoint that --resume continues from ----------------------------------------------------

def test_ctrl_c_saves_a_checkpoint_and_resume_continues(tmp_path, tiny, monkeypatch, capsys):
    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import BaseCallback

    class CtrlC(BaseCallback):
        def _on_step(self) -> bool:
            if self.num_timesteps >= 300:  # within the third rollout of 128 steps
                raise KeyboardInterrupt
            return True

    make_callbacks = train._make_callbacks
    monkeypatch.setattr(train, "_make_callbacks", lambda *a, **k: [*make_callbacks(*a, **k), CtrlC()])
    run = tmp_path / "run"
    with pytest.raises(SystemExit) as exc:
        try:
            train.main([ENV, "--timesteps", "640", "--out", str(run), "--config", tiny(), *SMALL])
        except KeyboardInterrupt as error:  # not caught: fail this test rather than stop the session
            pytest.fail(f"Ctrl-C escaped train.main: {error!r}")
    assert exc.value.code == 130
    err = capsys.readouterr().err
    assert "Traceback" not in err and f"--resume {run}" in err and "300 of 640" in err
    steps, model, vn = common.checkpoints(run)[-1]
    assert steps == 300 and vn.is_file()
    assert PPO.load(str(model), device="cpu").num_timesteps == 300
    with vn.open("rb") as fh:
        assert pickle.load(fh).obs_rms.count > 250  # the statistics of the steps taken
    summary = json.loads((run / "summary.json").read_text())
    assert summary["interrupted"] is True and summary["num_timesteps"] == 300
    assert summary["sessions"][-1]["interrupted"] is True
    assert PPO.load(str(run / "final_model.zip"), device="cpu").num_timesteps == 300

    monkeypatch.setattr(train, "_make_callbacks", make_callbacks)
    summary = train.main(["--resume", str(run), "--no-progress-bar"])  # on to the run's 640
    assert [(s["start_timesteps"], s["interrupted"]) for s in summary["sessions"]] == [(0, True), (300, False)]
    assert summary["num_timesteps"] >= 640 and summary["interrupted"] is False
    assert common.checkpoints(run)[-1][0] == summary["num_timesteps"]


def test_sigint_exits_130_without_traceback(tmp_path, tiny):
    """The real signal, in a child process: one line on stderr, status 130, a checkpoint."""
    run = tmp_path / "run"
    proc = subprocess.Popen(
        [sys.executable, "-m", "training.train", ENV, "--timesteps", "1000000", "--out", str(run),
         "--config", tiny(checkpoint_freq=0, eval={"freq": 0}), *SMALL],
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))  # not inherited as ignored
    try:
        deadline = time.time() + 60
        while not (run / "tb").exists() and proc.poll() is None and time.time() < deadline:
            time.sleep(0.1)  # tb/ is made as learning starts
        time.sleep(0.5)
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 130, (out, err)
    assert "Traceback" not in err and f"--resume {run}" in err
    steps = common.checkpoints(run)[-1][0]
    assert steps > 0 and json.loads((run / "summary.json").read_text())["num_timesteps"] == steps


# -- 3: 0 and negative counts ---------------------------------------------------------------------------------------

@pytest.mark.parametrize("parser, argv", [
    (train.build_parser, [ENV, "--timesteps", "0"]),
    (train.build_parser, [ENV, "--num-envs", "0"]),
    (train.build_parser, [ENV, "--eval-freq", "-1"]),
    (train.build_parser, [ENV, "--checkpoint-freq", "-5"]),
    (train.build_parser, [ENV, "--eval-episodes", "0"]),
    (train.build_parser, [ENV, "--threads", "0"]),
    (evaluate.build_parser, ["RUN", "--num-envs", "0"]),
    (evaluate.build_parser, ["RUN", "--episodes", "0"]),
    (push_sweep.build_parser, ["RUN", "--num-envs", "0"]),
    (push_sweep.build_parser, ["RUN", "--episodes", "-2"]),
    (push_trials.build_parser, ["RUN", "--directions", "0"]),
    (plot.build_parser, ["RUN", "--window", "0"]),
])
def test_non_positive_counts_are_argparse_errors(parser, argv, capsys):
    with pytest.raises(SystemExit) as exc:
        parser().parse_args(argv)
    assert exc.value.code == 2
    assert f"argument {argv[-2]}: must be an integer >= " in capsys.readouterr().err


@pytest.mark.parametrize("parser, argv", [
    (train.build_parser, [ENV, "--sim-threads", "0"]),
    (train.build_parser, [ENV, "--sim-threads", "many"]),
    (evaluate.build_parser, ["RUN", "--sim-threads", str(common.cores() + 1)]),
    (push_sweep.build_parser, ["RUN", "--sim-threads", "-1"]),
    (push_trials.build_parser, ["RUN", "--sim-threads", "0"]),
])
def test_bad_sim_threads_are_argparse_errors(parser, argv, capsys):
    with pytest.raises(SystemExit) as exc:
        parser().parse_args(argv)
    assert exc.value.code == 2
    assert (f"argument --sim-threads: must be an integer in 1..{common.cores()} (NUMBA_NUM_THREADS), got "
            f"{argv[-1]!r}") in capsys.readouterr().err


@pytest.mark.parametrize("parser, argv", [
    (train.build_parser, [ENV]), (evaluate.build_parser, ["RUN"]), (push_sweep.build_parser, ["RUN"]),
    (push_trials.build_parser, ["RUN"]),
])
def test_processes_is_a_deprecated_alias_of_sim_threads(parser, argv, capsys):
    """--processes N (the former worker processes) is --sim-threads min(N,
    cores), with a note; 0 stays a usage error naming it; --threads stays
    torch's CPU threads."""
    args = parser().parse_args(argv + ["--processes", "1"])
    assert args.sim_threads == 1 and "--processes is deprecated" in capsys.readouterr().err
    args = parser().parse_args(argv + ["--processes", "1000", "--threads", "3"])
    assert args.sim_threads == common.cores() and args.threads == 3
    assert parser().parse_args(argv).sim_threads is None
    with pytest.raises(SystemExit):
        parser().parse_args(argv + ["--processes", "0"])
    assert "argument --processes: must be an integer >= 1" in capsys.readouterr().err


def test_zero_eval_and_checkpoint_freq_turn_them_off(tmp_path, tiny):
    """--eval-freq 0: no evaluations (nor best model); --checkpoint-freq 0:
    only the checkpoint at the end; summary.json lists only files that exist."""
    run = tmp_path / "run"
    summary = train.main([ENV, "--timesteps", "384", "--out", str(run), "--config", tiny(),
                          "--eval-freq", "0", "--checkpoint-freq", "0", *SMALL])
    assert [s for s, _, _ in common.checkpoints(run)] == [384]
    assert not (run / "eval" / "evaluations.npz").exists() and not (run / "best_model.zip").exists()
    saved = json.loads((run / "config.json").read_text())["config"]
    assert saved["eval"]["freq"] == 0 and saved["checkpoint_freq"] == 0
    assert summary["evaluations"]["timesteps"] == [] and "evaluations" not in summary["files"]
    assert "best_model" not in summary["files"]
    for name in summary["files"].values():
        assert (run / name).exists(), name


def test_summary_lists_evaluations_when_they_exist(tiny_run):
    files = json.loads((tiny_run / "summary.json").read_text())["files"]
    assert files["evaluations"] == "eval/evaluations.npz" and files["best_model"] == "best_model.zip"
    for name in files.values():
        assert (tiny_run / name).exists(), name


@pytest.mark.parametrize("bad, message, extra", [
    ({"timesteps": 0}, "timesteps must be a whole number >= 1, got 0", ["--num-envs", "2"]),
    ({"num_envs": -1}, "num_envs must be a whole number >= 1, got -1", ["--timesteps", "128"]),
    ({"eval": {"freq": -1}}, "eval.freq", ["--timesteps", "128", "--num-envs", "2"]),
    ({"checkpoint_freq": "often"}, "checkpoint_freq", ["--timesteps", "128", "--num-envs", "2"]),
])
def test_bad_counts_in_a_config_are_named(tmp_path, bad, message, extra):
    argv = [ENV, "--out", str(tmp_path / "run"), "--config", _config(tmp_path, "bad", bad), "--no-progress-bar"]
    with pytest.raises(SystemExit) as exc:
        train.main(argv + extra)
    assert message in str(exc.value.code)
    assert not (tmp_path / "run").exists()


# -- 4: unknown config keys -----------------------------------------------------------------------------------------

def test_unknown_top_level_config_key_is_named(tmp_path):
    with pytest.raises(SystemExit) as exc:
        train.main([ENV, "--out", str(tmp_path / "run"), "--no-progress-bar",
                    "--config", _config(tmp_path, "lr", {"learning_rate": 0.1})])
    msg = str(exc.value.code)
    assert "'learning_rate'" in msg and 'under "ppo"' in msg
    assert all(key in msg for key in KEYS)
    assert not (tmp_path / "run").exists()
    with pytest.raises(ValueError, match="'frq' in \"eval\""):
        check_override({"eval": {"frq": 1}})
    with pytest.raises(ValueError, match="'ppo' must be a mapping"):
        check_override({"ppo": 3e-4})
    check_override({"residual": None, "train_env_kwargs": {"push_strength": [10, 30]}, "policy_warmup_steps": 0})
    for entry in CONFIGS.values():  # every shipped entry is a valid override of itself
        check_override(entry)


# -- 6: a resume with nothing to do ---------------------------------------------------------------------------------

def test_resume_with_nothing_to_do_changes_nothing(tiny_run, tmp_path, capsys):
    run = tmp_path / "done"
    shutil.copytree(tiny_run, run)
    before = {p.relative_to(run): (p.read_bytes(), os.stat(p).st_mtime_ns) for p in run.rglob("*") if p.is_file()}
    for total in ("512", "256"):
        summary = train.main(["--resume", str(run), "--timesteps", total, "--no-progress-bar"])
        assert "nothing to do" in capsys.readouterr().out
        assert summary["num_timesteps"] == 512 and summary["timesteps_requested"] == 512
    after = {p.relative_to(run): (p.read_bytes(), os.stat(p).st_mtime_ns) for p in run.rglob("*") if p.is_file()}
    assert after == before
