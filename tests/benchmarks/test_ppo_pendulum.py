import json
import math
import tempfile

import pytest

pytest.importorskip("stable_baselines3")

from benchmarks.ppo_pendulum import main  # noqa: E402

KEYS = {"env_id", "engine", "seed", "solved_at_steps", "solved_at_wall_s", "final_eval_return", "train_wall_s",
        "env_steps"}


@pytest.mark.parametrize("engine", ["ragdoll", "mujoco"])
def test_short_run_writes_rows(tmp_path, engine, monkeypatch):
    if engine == "mujoco":
        pytest.importorskip("mujoco")
    path = tmp_path / "ppo.json"
    scratch = tmp_path / "tmp"
    scratch.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(scratch))  # where SB3's default logger makes SB3-<date>
    # An impossible threshold: the run goes to --max-steps and reports null.
    main(["--seeds", "0", "--engines", engine, "--max-steps", "2048", "--eval-freq", "1024",
          "--eval-episodes", "1", "--threshold", "2.0", "--json", str(path)])
    rows = json.loads(path.read_text())
    assert len(rows) == 1
    row = rows[0]
    assert KEYS <= row.keys()
    assert row["env_id"] == ("Ragdoll/InvertedPendulum-v0" if engine == "ragdoll" else "InvertedPendulum-v5")
    assert row["seed"] == 0 and row["env_steps"] >= 2048
    assert row["solved_at_steps"] is None and row["solved_at_wall_s"] is None
    assert 0.0 < row["final_eval_return"] <= 1000.0
    assert math.isfinite(row["train_wall_s"]) and row["train_wall_s"] > 0
    assert not list(scratch.glob("SB3-*")), "the benchmark left an SB3 log folder in the temporary directory"


def test_solved_run_reports_steps_and_seconds(tmp_path):
    path = tmp_path / "ppo.json"
    # Threshold 0: the first evaluation counts as solved.
    main(["--seeds", "0", "--engines", "ragdoll", "--max-steps", "8192", "--eval-freq", "1024",
          "--eval-episodes", "1", "--threshold", "0.0", "--json", str(path)])
    row = json.loads(path.read_text())[0]
    assert row["solved_at_steps"] is not None and 1024 <= row["solved_at_steps"] <= 4096
    assert 0.0 < row["solved_at_wall_s"] <= row["train_wall_s"] + 1e-9
