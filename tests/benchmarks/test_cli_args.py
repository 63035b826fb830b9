"""The benchmark command lines: bad option values are usage errors (exit 2,
a message naming the option) before anything runs, and every command that
benchmarks/README.md shows parses."""

from __future__ import annotations

import importlib
import json
import re
import shlex
from pathlib import Path

import numba
import pytest

from benchmarks import accuracy, effects, stability, throughput
from benchmarks.common import settings_json

README = Path(__file__).resolve().parents[2] / "benchmarks" / "README.md"


def usage_error(capsys, parse, argv) -> str:
    """``parse(argv)`` must stop with argparse's usage error; its message."""
    with pytest.raises(SystemExit) as exc:
        parse(argv)
    assert exc.value.code == 2
    return capsys.readouterr().err


# ------------------------------------------------------------------ stability
@pytest.fixture
def no_case_runs(monkeypatch):
    def fail(*args, **kwargs):
        raise AssertionError("a case ran before the options were checked")

    monkeypatch.setattr(stability, "make_case", fail)
    monkeypatch.setattr(stability, "run_case", fail)


def test_stability_unknown_setting_is_a_usage_error_listing_the_settings(capsys, no_case_runs):
    err = usage_error(capsys, stability.main, ["--quick", "--settings", '{"substep": 8}'])
    assert "python -m benchmarks.stability" in err  # prog, not stability.py
    assert "argument --settings" in err and "'substep'" in err and "did you mean 'substeps'" in err
    assert "joint_hertz" in err and "check_finite" in err  # the valid names are listed


@pytest.mark.parametrize("text, words", [
    ('{"substeps": 0}', ["substeps", ">= 1"]),
    ('{"substeps": 2.5}', ["substeps", "integer"]),
    ('{"joint_limits_in_tree": 1}', ["joint_limits_in_tree", "true, false or null"]),
    ('{"integrator": "rk5"}', ["integrator", "rk5"]),
    ('{"joint_hertz": -1}', ["joint_hertz", "> 0"]),
    ('[8]', ["JSON object"]),
    ('{substeps: 8}', ["not valid JSON"]),
])
def test_stability_bad_setting_value_is_a_usage_error(capsys, no_case_runs, text, words):
    err = usage_error(capsys, stability.main, ["--case", "mass_ratio_stack", "--settings", text])
    assert "argument --settings" in err and "Traceback" not in err
    for w in words:
        assert w in err


def test_settings_json_keeps_good_settings():
    assert settings_json('{"substeps": 12, "joint_hertz": Infinity, "joint_limits_in_tree": true}') == {
        "substeps": 12, "joint_hertz": float("inf"), "joint_limits_in_tree": True}
    assert settings_json('{"dt": 0.01, "contact_hertz": 30}') == {"dt": 0.01, "contact_hertz": 30}


# ------------------------------------------------------------------- accuracy
def test_accuracy_from_json_missing_or_malformed_is_a_usage_error(tmp_path, capsys):
    missing = tmp_path / "nope.json"
    err = usage_error(capsys, accuracy.main, ["--from-json", str(missing), "--out-dir", str(tmp_path)])
    assert "--from-json" in err and "no such file" in err and "--json PATH" in err
    bad = tmp_path / "bad.json"
    for text, words in [("{", "not JSON"), ('{"rows": []}', "not a JSON list"),
                        ('[{"scenario": "pendulum"}]', "row 0"), ("[]", "no rows")]:
        bad.write_text(text)
        err = usage_error(capsys, accuracy.main, ["--from-json", str(bad), "--out-dir", str(tmp_path)])
        assert words in err, (text, err)
    assert not (tmp_path / "accuracy.md").exists()


def test_accuracy_json_round_trips_through_from_json(tmp_path, capsys):
    """``--json PATH`` writes the rows and ``--from-json PATH`` redraws the
    report from them: the README's two commands."""
    rows_path = tmp_path / "rows" / "accuracy.json"
    accuracy.main(["--quick", "--scenarios", "spring", "--settings", "default", "--duration-scale", "0.2",
                   "--no-mujoco", "--no-plot", "--out-dir", str(tmp_path / "run"), "--json", str(rows_path)])
    assert {p.name for p in (tmp_path / "run").iterdir()} == {"accuracy.md"}  # JSON only where --json said
    rows = json.loads(rows_path.read_text())
    assert [r["scenario"] for r in rows] == ["spring"]
    accuracy.main(["--quick", "--duration-scale", "0.2", "--no-plot", "--from-json", str(rows_path),
                   "--out-dir", str(tmp_path / "redraw")])
    md = (tmp_path / "redraw" / "accuracy.md").read_text()
    assert "## spring" in md and "Simulated seconds: spring 1." in md  # only the file's scenarios
    capsys.readouterr()
    err = usage_error(capsys, accuracy.main, ["--from-json", str(rows_path), "--json", str(tmp_path / "x.json")])
    assert "--from-json" in err and "--json" in err


@pytest.mark.parametrize("argv", [["--repeats", "0"], ["--duration-scale", "inf"], ["--duration-scale", "-1"]])
def test_accuracy_bad_numbers_are_usage_errors(capsys, argv):
    err = usage_error(capsys, accuracy.parse_args, argv)
    assert f"argument {argv[0]}" in err


# ----------------------------------------------------- throughput and effects
@pytest.mark.parametrize("argv", [
    ["--repeats", "0"],  # was taken as "not given": 3 repeats
    ["--quick", "--steps", "0"],  # was taken as "not given": 3 steps
    ["--worlds", "1", "0"], ["--mujoco-worlds", "-4"], ["--target-seconds", "nan"], ["--threads", "0"],
    ["--threads", "1", str(numba.config.NUMBA_NUM_THREADS + 1)], ["--threads", "two"],
])
def test_throughput_bad_numbers_are_usage_errors(capsys, argv):
    err = usage_error(capsys, throughput.parse_args, argv)
    assert "argument " + next(a for a in reversed(argv) if a.startswith("--")) in err


@pytest.mark.parametrize("argv", [["--worlds", "0"], ["--seconds", "nan"], ["--threads", "0"], ["--top", "-1"]])
def test_profile_step_bad_numbers_are_usage_errors(capsys, argv):
    from benchmarks import profile_step

    err = usage_error(capsys, profile_step.parse_args, argv)
    assert f"argument {argv[0]}" in err


def test_throughput_threads_default_to_one_and_all_cores():
    cores = numba.config.NUMBA_NUM_THREADS
    assert throughput.parse_args([]).threads == sorted({1, cores})
    assert throughput.parse_args(["--threads", str(cores), "1", "1"]).threads == sorted({1, cores})


@pytest.mark.parametrize("argv", [
    ["--repeats", "0"],  # was taken as "not given": 5 repeats
    ["--quick", "--steps", "0"], ["--worlds", "0"], ["--settle-steps", "-1"], ["--target-seconds", "0"],
])
def test_effects_bad_numbers_are_usage_errors(capsys, argv):
    err = usage_error(capsys, effects.parse_args, argv)
    assert "argument " + next(a for a in reversed(argv) if a.startswith("--")) in err


@pytest.mark.parametrize("argv", [
    ["--max-steps", "0"], ["--eval-freq", "-5"], ["--eval-episodes", "0"], ["--seeds", "0", "-1"],
    ["--threshold", "-0.5"], ["--threshold", "inf"], ["--threshold", "nan"],
])
def test_ppo_pendulum_bad_numbers_are_usage_errors(capsys, argv):
    from benchmarks import ppo_pendulum

    err = usage_error(capsys, ppo_pendulum.parse_args, argv)
    assert "argument " + next(a for a in reversed(argv) if a.startswith("--")) in err


# --------------------------------------------------------------------- README
def readme_commands():
    """(module, argv) of every ``python -m benchmarks.NAME ...`` line in the README's code blocks."""
    blocks = re.findall(r"```\n(.*?)```", README.read_text(encoding="utf-8"), flags=re.S)
    out = []
    for block in blocks:
        for line in block.splitlines():
            words = shlex.split(line, comments=True)
            if words[:2] == ["python", "-m"] and words[2].startswith("benchmarks."):
                out.append((words[2], words[3:]))
    return out


def test_every_readme_command_parses():
    commands = readme_commands()
    assert {m for m, _ in commands} == {"benchmarks.throughput", "benchmarks.accuracy", "benchmarks.effects",
                                        "benchmarks.ppo_pendulum", "benchmarks.stability"}
    for module, argv in commands:
        importlib.import_module(module).parse_args(argv)  # a usage error would raise SystemExit
