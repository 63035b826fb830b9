"""``python -m ragdoll_env.demo``: bad numbers are usage errors before anything
runs (no silent one-step run for ``--seconds -1``, no traceback from the
renderer for ``--width 0``), and good ones reach ``run``."""

from __future__ import annotations

import pytest

from ragdoll_env import demo


@pytest.fixture
def runs(monkeypatch):
    calls = []

    def fake_run(*args, **kwargs):
        calls.append((args, kwargs))
        return {}

    monkeypatch.setattr(demo, "run", fake_run)
    return calls


@pytest.mark.parametrize("option, value", [
    ("--seconds", "-1"), ("--seconds", "0"), ("--seconds", "nan"), ("--seconds", "inf"),
    ("--width", "0"), ("--height", "-2"), ("--width", "1.5"), ("--fps", "0"), ("--frames", "0"),
    ("--seed", "-1"),
])
def test_bad_numbers_are_usage_errors(tmp_path, capsys, runs, option, value):
    with pytest.raises(SystemExit) as exc:
        demo.main(["--out", str(tmp_path), option, value])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert f"argument {option}" in err and repr(value) in err
    assert runs == []


def test_out_must_be_a_directory(tmp_path, capsys, runs):
    f = tmp_path / "file"
    f.write_text("")
    with pytest.raises(SystemExit):
        demo.main(["--out", str(f)])
    assert "--out" in capsys.readouterr().err and runs == []


def test_good_numbers_reach_run(tmp_path, runs):
    assert demo.main(["--out", str(tmp_path), "--seconds", "0.5", "--width", "64", "--height", "48",
                      "--fps", "15", "--frames", "2", "--seed", "3", "--scene", "boxes"]) == 0
    (args, kwargs), = runs
    assert args == (str(tmp_path), "boxes", 2, 0.5, False, 64, 48)
    assert kwargs == {"fps": 15, "seed": 3}


@pytest.mark.parametrize("kwargs", [{"seconds": -1.0}, {"seconds": 0.0}, {"fps": 0}])
def test_run_rejects_what_would_silently_run_one_step(tmp_path, kwargs):
    with pytest.raises(ValueError):
        demo.run(str(tmp_path / "out"), **kwargs)
    assert not (tmp_path / "out").exists()
