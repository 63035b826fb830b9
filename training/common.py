"""Shared helpers of the training CLIs: env ids, run directories, loading, versions."""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import platform
import re
import signal
import sys
import threading
from pathlib import Path

from ragdoll_env.cli_args import non_negative_int, positive_int  # noqa: F401 (argparse types of the CLIs: C.positive_int)

CHECKPOINT_DIR = "checkpoints"
CHECKPOINT_PREFIX = "ppo"
EVAL_DIR = "eval"
CONFIG_FILE = "config.json"
SUMMARY_FILE = "summary.json"
FINAL_MODEL = "final_model.zip"
FINAL_VECNORM = "vecnormalize.pkl"
BEST_MODEL = "best_model.zip"
BEST_VECNORM = "best_vecnormalize.pkl"

ACTIVATIONS = {"tanh": "Tanh", "relu": "ReLU", "elu": "ELU", "leaky_relu": "LeakyReLU"}


class TrainingError(ValueError):
    """A user-facing error of the training CLIs (bad id, missing run, corrupted file)."""


class TrainingInterrupted(KeyboardInterrupt):
    """Training stopped by Ctrl-C after the run was saved (checkpoint, final
    model, summary); the message says how to continue it, ``summary`` is the
    run's summary. Still a KeyboardInterrupt for callers of ``train()``; the
    CLIs print the message and exit with status 130."""

    def __init__(self, message: str, summary: dict | None = None):
        super().__init__(message)
        self.summary = summary


def known_env_ids() -> tuple[str, ...]:
    import ragdoll_env

    return tuple(ragdoll_env.ENV_IDS)


def resolve_env_id(name: str) -> str:
    """The registered Ragdoll id for ``name`` ("Ragdoll/X-v0", "X-v0" or
    "ragdoll_env:Ragdoll/X-v0"), else TrainingError naming it and the known ids."""
    ids = known_env_ids()
    key = str(name).split(":")[-1]
    for candidate in (key, "Ragdoll/" + key):
        if candidate in ids:
            return candidate
    raise TrainingError(f"unknown environment id {name!r}; known Ragdoll ids: {', '.join(ids)}")


def env_slug(env_id: str) -> str:
    return env_id.split("/")[-1]


def load_config_file(path) -> dict:
    """A dict from a JSON or YAML file (TrainingError if missing or malformed)."""
    p = Path(path)
    if not p.is_file():
        raise TrainingError(f"config file {str(p)!r} does not exist")
    text = p.read_text()
    try:
        if p.suffix.lower() in (".yaml", ".yml"):
            import yaml

            data = yaml.safe_load(text)
        else:
            data = json.loads(text)
    except Exception as exc:  # noqa: BLE001 - reported as a clear message
        raise TrainingError(f"cannot parse config file {str(p)!r}: {exc}") from exc
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise TrainingError(f"config file {str(p)!r} must hold a mapping, got {type(data).__name__}")
    return data


def policy_kwargs(kwargs: dict | None) -> dict:
    """Policy kwargs with ``activation_fn`` given by name turned into the torch class."""
    import torch.nn as nn

    out = dict(kwargs or {})
    act = out.get("activation_fn")
    if isinstance(act, str):
        name = ACTIVATIONS.get(act.lower(), act)
        if not hasattr(nn, name):
            raise TrainingError(f"unknown activation_fn {act!r}; use one of {sorted(ACTIVATIONS)}")
        out["activation_fn"] = getattr(nn, name)
    return out


def ppo_arguments(ppo: dict) -> tuple:
    """(policy, keyword arguments) for ``stable_baselines3.PPO`` from a
    config's ``ppo`` mapping: ``policy`` (default "MlpPolicy") taken out,
    ``activation_fn`` names turned into torch classes, and for ``MlpPolicy``
    with a ``critic_lr_factor`` in its ``policy_kwargs`` the policy whose
    critic steps at that multiple of the learning rate
    (:mod:`training.policies`; a null factor counts as not given)."""
    kwargs = dict(ppo)
    policy = kwargs.pop("policy", "MlpPolicy")
    pk = policy_kwargs(kwargs.get("policy_kwargs"))
    if pk.get("critic_lr_factor", 0) is None:
        del pk["critic_lr_factor"]
    if "critic_lr_factor" in pk:
        from .policies import CriticRatePolicy

        if policy not in ("MlpPolicy", CriticRatePolicy):
            raise TrainingError(f"critic_lr_factor is a setting of MlpPolicy, not of {policy!r}")
        policy = CriticRatePolicy
    kwargs["policy_kwargs"] = pk
    return policy, kwargs


def require_run_dir(path) -> Path:
    p = Path(path)
    if not p.is_dir():
        raise TrainingError(f"run directory {str(p)!r} does not exist")
    if not (p / CONFIG_FILE).is_file():
        raise TrainingError(f"{str(p)!r} is not a training run directory (no {CONFIG_FILE}; "
                            "make one with python -m training.train ENV_ID --out DIR)")
    return p


#: Settings fields that never change a trajectory, left out of a run's record.
_NOT_PHYSICS = ("check_finite", "world_chunk")


def engine_settings(venv) -> dict:
    """The engine settings of the batched core under ``venv`` (any SB3
    wrappers), as recorded in a run's config.json: every field of
    ``engine.Settings`` that changes a trajectory."""
    from dataclasses import asdict

    return {k: v for k, v in asdict(venv.core.settings).items() if k not in _NOT_PHYSICS}


#: Settings fields added to the engine after runs began recording their
#: settings, each with the value that steps as the engine did before it: a
#: run that did not record one of them was trained with that value.
ADDED_SETTINGS = {"static_contact_projection_depth": math.inf}


def settings_changes(recorded: dict | None, current: dict) -> dict:
    """{field: (recorded, current)} for the fields whose values differ. A
    field the run did not record counts as its ``ADDED_SETTINGS`` value, or,
    if it is not there, with None as its recorded value (added to the engine
    since, stepping otherwise); empty when the run recorded none (runs before
    2026-12-04)."""
    if not recorded:
        return {}
    recorded = {**ADDED_SETTINGS, **recorded}
    return {k: (recorded.get(k), v) for k, v in current.items() if k not in recorded or recorded[k] != v}


#: Keyword arguments added to a residual's baseline after runs began
#: training on it, each with the value that acts as the baseline did before:
#: a run whose residual did not record one was trained with that value
#: (``StandingPD``'s lifted-foot ankle gains came on 2026-12-05).
ADDED_BASELINE_KWARGS = {"standing_pd": {"lifted_ankle": 1.0}}


def _baseline_name(name, env_id):
    """The specific name of the baseline ``name`` on ``env_id`` ("pd" is the
    standing PD on Balance)."""
    return "standing_pd" if name == "pd" and env_id == "Ragdoll/Balance-v0" else name


def residual_as_trained(residual, env_id):
    """A run's recorded ``residual`` entry with the baseline keyword
    arguments it did not record at their ``ADDED_BASELINE_KWARGS`` values
    (None for none)."""
    if not isinstance(residual, dict):
        return residual
    added = ADDED_BASELINE_KWARGS.get(_baseline_name(residual.get("baseline"), env_id))
    if not added:
        return residual
    return {**residual, "kwargs": {**added, **(residual.get("kwargs") or {})}}


def baseline_kwargs(name, residual, env_id) -> dict:
    """Keyword arguments of the baseline ``name`` beside a run of ``env_id``:
    those of the run's residual when it is built on that baseline (the PD
    the policy starts from), else none (the defaults)."""
    if isinstance(residual, dict) and _baseline_name(residual.get("baseline"), env_id) == _baseline_name(name, env_id):
        return dict(residual.get("kwargs") or {})
    return {}


def read_run_config(run_dir) -> dict:
    """A run's config.json, its residual entry as trained (``residual_as_trained``)."""
    p = require_run_dir(run_dir) / CONFIG_FILE
    try:
        saved = floats_from_json(json.loads(p.read_text()))
    except Exception as exc:  # noqa: BLE001
        raise TrainingError(f"cannot read {str(p)!r}: {exc}") from exc
    config = saved.get("config") if isinstance(saved, dict) else None
    if isinstance(config, dict) and config.get("residual"):
        config["residual"] = residual_as_trained(config["residual"], saved.get("env_id"))
    if isinstance(config, dict):
        saved["config"] = run_config_threads(config, p)
    return saved


def run_config_threads(config: dict, path) -> dict:
    """A run's recorded ``config`` with its physics threads as this machine
    steps them: the ``processes`` of a run recorded before the worlds stepped
    on threads read as ``threads`` (:func:`training.configs.upgrade`), and a
    count above ``cores()`` (a run from a larger machine) cut to
    ``cores()``; the thread count changes no result."""
    from .configs import upgrade

    try:
        config = upgrade(config)
    except ValueError as exc:
        raise TrainingError(f"{str(path)!r}: {exc}") from exc
    threads = config.get("threads")
    if isinstance(threads, int) and not isinstance(threads, bool) and threads > cores():
        config = {**config, "threads": cores()}
    return config


_CKPT = re.compile(rf"^{CHECKPOINT_PREFIX}_(\d+)_steps\.zip$")


def checkpoints(run_dir) -> list[tuple[int, Path, Path]]:
    """[(timesteps, model.zip, vecnormalize.pkl)] of the run's checkpoints, oldest first."""
    d = Path(run_dir) / CHECKPOINT_DIR
    out = []
    if d.is_dir():
        for f in d.iterdir():
            m = _CKPT.match(f.name)
            if m:
                steps = int(m.group(1))
                out.append((steps, f, d / f"{CHECKPOINT_PREFIX}_vecnormalize_{steps}_steps.pkl"))
    return sorted(out)


def last_checkpoint(run_dir) -> tuple[int, Path, Path]:
    """(timesteps, model, vecnormalize) of the latest checkpoint, for --resume."""
    ckpts = checkpoints(run_dir)
    if not ckpts:
        raise TrainingError(f"run directory {str(run_dir)!r} has no checkpoint in {CHECKPOINT_DIR}/ to resume from; "
                            "a run that stopped before its first checkpoint starts afresh with "
                            f"python -m training.train ENV_ID --out {run_dir}")
    return ckpts[-1]


def saved_models(run_dir) -> list[Path]:
    """The models a run directory holds (checkpoints, final and best model):
    what a fresh start must not overwrite. A directory with a config.json but
    none of these is a run that stopped before its first checkpoint."""
    run = Path(run_dir)
    return [m for _, m, _ in checkpoints(run)] + [run / n for n in (FINAL_MODEL, BEST_MODEL) if (run / n).is_file()]


#: which model of a run ``--model`` picks: best (the default), final or the last checkpoint
MODEL_CHOICES = ("best", "final", "last")


def add_model_argument(p) -> None:
    """``--model {best,final,last,STEPS}`` of the evaluation CLIs."""
    p.add_argument("--model", type=model_choice, default="best", metavar="{best,final,last,STEPS}",
                   help="which model of the run: best (the default; else final, else the last checkpoint), final "
                        "(at the end of its last session), last (its last checkpoint) or STEPS (its checkpoint at "
                        "that many timesteps)")


def model_choice(text: str) -> str:
    """``--model``'s value: one of MODEL_CHOICES or a checkpoint's timesteps."""
    if text in MODEL_CHOICES or (text.isdigit() and int(text) > 0):
        return text
    raise argparse.ArgumentTypeError(f"expected one of {', '.join(MODEL_CHOICES)} or a checkpoint's timesteps, "
                                     f"got {text!r}")


def cores() -> int:
    """The threads numba can step the worlds on (``NUMBA_NUM_THREADS``)."""
    from engine import max_threads

    return max_threads()


def sim_threads(text: str) -> int:
    """argparse type of ``--sim-threads``: an integer in 1..``cores()``."""
    try:
        value = int(text)
    except ValueError:
        value = None
    if value is None or not 1 <= value <= cores():
        raise argparse.ArgumentTypeError(f"must be an integer in 1..{cores()} (NUMBA_NUM_THREADS), got {text!r}")
    return value


class _DeprecatedProcesses(argparse.Action):
    """``--processes N``: the deprecated alias of ``--sim-threads``, as
    ``--sim-threads min(N, cores())``, with a note on stderr."""

    def __call__(self, parser, namespace, values, option_string=None):
        threads = min(values, cores())
        print(f"note: {option_string} is deprecated: the worlds step on threads; use --sim-threads (taking "
              f"--sim-threads {threads})", file=sys.stderr)
        setattr(namespace, self.dest, threads)


#: help of ``--sim-threads`` in the evaluation CLIs
SIM_THREADS_HELP = ("physics threads stepping each env's worlds (engine.set_threads): the same results bit for bit, "
                    "faster on several cores (default: the run's, as its config.json says; all cores for runs that "
                    "name none)")


def add_sim_threads_argument(p, help_text: str = SIM_THREADS_HELP) -> None:
    """``--sim-threads N`` (and ``--processes N``, its deprecated alias) of the
    CLIs; ``--threads`` is torch's CPU threads."""
    p.add_argument("--sim-threads", type=sim_threads, default=None, metavar="N", help=help_text)
    p.add_argument("--processes", type=positive_int, dest="sim_threads", action=_DeprecatedProcesses,
                   metavar="N", help="deprecated alias of --sim-threads (the worlds no longer step in worker "
                                     "processes): --sim-threads min(N, cores)")


def whole_number(value, name: str, minimum: int) -> int:
    """``value`` of config key ``name`` as an int >= ``minimum`` (an integral
    float such as 1e5 counts), else TrainingError."""
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise TrainingError(f"{name} must be a whole number >= {minimum}, got {value!r}")
    return value


def physics_threads(value, name: str = "threads (physics threads per env)") -> int | None:
    """A config's ``threads``: None (all cores) or a whole number in
    1..``cores()``, else TrainingError naming ``name``."""
    if value is None:
        return None
    value = whole_number(value, name, 1)
    if value > cores():
        raise TrainingError(f"{name} must be at most {cores()} (NUMBA_NUM_THREADS, the cores here), got {value!r}")
    return value


def run_threads(threads, saved: dict) -> int | None:
    """``threads`` if given, else the run's (``saved``: its config.json, read
    by :func:`read_run_config`), else None (all cores)."""
    if threads is not None:
        return int(threads)
    return physics_threads(saved["config"].get("threads"), "the run's config.json: threads")


def with_threads(env_kwargs: dict, threads: int | None) -> dict:
    """``env_kwargs`` for an env whose worlds step on ``threads`` physics
    threads (None: all cores; this count replaces any in ``env_kwargs``)."""
    return {**env_kwargs, "threads": None if threads is None else int(threads)}


def model_for_evaluation(run_dir, which: str = "best") -> tuple[str, Path, Path | None]:
    """(label, model, vecnormalize or None) of a run. ``which`` "best": the
    best model, else the final one, else the last checkpoint; "final": the
    model at the end of its last session; "last": its last checkpoint; a
    number of timesteps (as a string of digits): its checkpoint there."""
    run = Path(run_dir)
    if str(which).isdigit():
        ckpts = {steps: (model, vn) for steps, model, vn in checkpoints(run)}
        if int(which) not in ckpts:
            raise TrainingError(f"run directory {str(run)!r} has no checkpoint at {int(which)} timesteps; it has "
                                f"{sorted(ckpts) or 'none'}")
        model, vn = ckpts[int(which)]
        return f"checkpoint_{int(which)}", model, vn if vn.is_file() else None
    if which not in MODEL_CHOICES:
        raise TrainingError(f"model must be one of {MODEL_CHOICES} or a checkpoint's timesteps, got {which!r}")
    if which == "best" and (run / BEST_MODEL).is_file():
        vn = run / BEST_VECNORM if (run / BEST_VECNORM).is_file() else run / FINAL_VECNORM
        return "best_model", run / BEST_MODEL, vn if vn.is_file() else None
    if which in ("best", "final") and (run / FINAL_MODEL).is_file():
        vn = run / FINAL_VECNORM
        return "final_model", run / FINAL_MODEL, vn if vn.is_file() else None
    ckpts = checkpoints(run)
    if which in ("best", "last") and ckpts:
        steps, model, vn = ckpts[-1]
        return f"checkpoint_{steps}", model, vn if vn.is_file() else None
    wanted = {"best": f"{BEST_MODEL}, {FINAL_MODEL} or {CHECKPOINT_DIR}/{CHECKPOINT_PREFIX}_*_steps.zip",
              "final": FINAL_MODEL, "last": f"{CHECKPOINT_DIR}/{CHECKPOINT_PREFIX}_*_steps.zip"}[which]
    raise TrainingError(f"run directory {str(run)!r} holds no model ({wanted})")


def load_ppo(path, env=None, device="cpu", custom_objects=None):
    """PPO.load with a clear TrainingError for a missing or corrupted file."""
    from stable_baselines3 import PPO

    p = Path(path)
    if not p.is_file():
        raise TrainingError(f"model file {str(p)!r} does not exist")
    try:
        return PPO.load(str(p), env=env, device=device, custom_objects=custom_objects)
    except ImportError as exc:  # a policy class pickled by module path (training.policies) that is not there
        raise TrainingError(f"cannot load model {str(p)!r}: its policy class is not importable here "
                            f"({type(exc).__name__}: {exc}); install this package's training extra") from exc
    except Exception as exc:  # noqa: BLE001 - zipfile/pickle/torch errors become one message
        raise TrainingError(f"cannot load model {str(p)!r}: the file is corrupted or not a "
                            f"stable-baselines3 PPO model ({type(exc).__name__}: {exc})") from exc


def load_vecnormalize(path, venv):
    """VecNormalize.load with a clear TrainingError for a missing or corrupted file."""
    from stable_baselines3.common.vec_env import VecNormalize

    p = Path(path)
    if not p.is_file():
        raise TrainingError(f"normalisation statistics {str(p)!r} do not exist")
    try:
        return VecNormalize.load(str(p), venv)
    except Exception as exc:  # noqa: BLE001
        raise TrainingError(f"cannot load normalisation statistics {str(p)!r}: the file is corrupted "
                            f"({type(exc).__name__}: {exc})") from exc


def versions() -> dict:
    import gymnasium
    import numpy
    import stable_baselines3
    import torch

    try:
        from importlib.metadata import version

        ragdoll = version("ragdoll")
    except Exception:  # noqa: BLE001
        ragdoll = "unknown"
    return {
        "python": sys.version.split()[0],
        "platform": platform.platform(),
        "numpy": numpy.__version__,
        "torch": torch.__version__,
        "stable_baselines3": stable_baselines3.__version__,
        "gymnasium": gymnasium.__version__,
        "ragdoll": ragdoll,
    }


@contextlib.contextmanager
def sigint_ignored():
    """SIGINT (Ctrl-C) ignored inside the block, so that a second Ctrl-C does
    not cut a checkpoint or summary being written in half (main thread only;
    elsewhere a no-op)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, signal.default_int_handler if previous is None else previous)


def write_json(path, data) -> None:
    """``data`` as strict JSON (what other languages' parsers read): an
    infinite float is written as the string "inf" or "-inf" and NaN as null
    (``float_from_json`` reads the first two back)."""
    tmp = Path(str(path) + ".tmp")
    tmp.write_text(json.dumps(_strict_floats(data), indent=2, allow_nan=False) + "\n")
    os.replace(tmp, path)


def _strict_floats(obj):
    """``obj`` with its non-finite floats spelt as ``write_json`` says and
    other objects made JSON values (``_jsonable``)."""
    if isinstance(obj, float) and not math.isfinite(obj):
        return None if math.isnan(obj) else ("inf" if obj > 0 else "-inf")
    if isinstance(obj, dict):
        return {k: _strict_floats(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_strict_floats(v) for v in obj]
    if isinstance(obj, (str, int, float, bool, type(None))):
        return obj
    return _strict_floats(_jsonable(obj))


def float_from_json(value):
    """A value as ``write_json`` wrote it, with "inf" and "-inf" as floats
    again (runs written before 2026-12-06 hold the non-standard Infinity,
    which Python's json reads as a float already)."""
    return float(value) if isinstance(value, str) and value in ("inf", "-inf") else value


def floats_from_json(obj):
    """``float_from_json`` throughout a structure read from a run's JSON file
    (``read_run_config`` and the summary's reader apply it)."""
    if isinstance(obj, dict):
        return {k: floats_from_json(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [floats_from_json(v) for v in obj]
    return float_from_json(obj)


def _jsonable(obj):
    try:
        import numpy as np

        if isinstance(obj, np.generic):
            return obj.item()
        if isinstance(obj, np.ndarray):
            return obj.tolist()
    except ImportError:
        pass
    if isinstance(obj, Path):
        return str(obj)
    if isinstance(obj, type):
        return obj.__name__
    return repr(obj)


def run_cli(main_fn, argv=None):
    """Run ``main_fn(argv)``; a TrainingError exits with its message (SystemExit,
    status 1), Ctrl-C (KeyboardInterrupt) with a one-line message and status
    130, without a traceback."""
    try:
        return main_fn(argv)
    except TrainingError as exc:
        raise SystemExit(f"error: {exc}") from None
    except TrainingInterrupted as exc:
        print(f"interrupted: {exc}", file=sys.stderr, flush=True)
        raise SystemExit(130) from None
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr, flush=True)
        raise SystemExit(130) from None
