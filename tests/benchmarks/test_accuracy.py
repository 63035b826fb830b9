import json
import math

import pytest

from benchmarks.accuracy import PRIMARY, dominance_lines, main, thesis_dominance

SCENARIOS = ["pendulum", "spring", "bouncing_ball", "ragdoll"]


def finite_or_none(v):
    return v is None or (isinstance(v, float) and math.isfinite(v))


def test_quick_subset_writes_rows_markdown_and_plot(tmp_path):
    pytest.importorskip("matplotlib")
    path = tmp_path / "accuracy.json"
    main(["--quick", "--scenarios", *SCENARIOS, "--settings", "dt=1/30 sub=1", "thesis dt=1/60",
          "--duration-scale", "0.1", "--no-mujoco", "--json", str(path), "--out-dir", str(tmp_path)])
    rows = json.loads(path.read_text())
    assert isinstance(rows, list) and rows
    for r in rows:
        assert {"scenario", "settings", "errors", "wall_s_per_sim_s"} <= r.keys()
        assert r["scenario"] in SCENARIOS
        assert isinstance(r["settings"], dict) and isinstance(r["errors"], dict)
        assert all(finite_or_none(v) for v in r["errors"].values())
        assert r["wall_s_per_sim_s"] is None or r["wall_s_per_sim_s"] > 0
    for name in SCENARIOS:
        defaults = [r for r in rows if r["scenario"] == name and r["settings"].get("default") is True]
        assert len(defaults) == 1, name
        assert PRIMARY[name] in defaults[0]["errors"]
        assert defaults[0]["settings"]["solver"] == "soft_step"
    assert any(r["settings"].get("thesis_baseline") for r in rows)
    ragdoll = next(r for r in rows if r["scenario"] == "ragdoll" and r["settings"]["default"])
    assert {"anchor_error_max_m", "limit_violation_max_rad", "max_penetration_m", "pelvis_traj_max_m",
            "bodies_traj_rms_m"} <= ragdoll["errors"].keys()
    md = (tmp_path / "accuracy.md").read_text()
    assert "## pendulum" in md and "**default**" in md
    assert "## Against the thesis baseline" in md
    assert (tmp_path / "accuracy.png").stat().st_size > 0


def test_mujoco_reference_rows(tmp_path):
    pytest.importorskip("mujoco")
    path = tmp_path / "accuracy.json"
    main(["--quick", "--scenarios", "pendulum", "--settings", "default", "--duration-scale", "0.2",
          "--no-plot", "--json", str(path), "--out-dir", str(tmp_path)])
    rows = json.loads(path.read_text())
    mj = [r for r in rows if r["settings"].get("engine") == "mujoco"]
    assert {r["settings"]["timestep"] for r in mj} == {0.002, 0.0005}
    assert all(r["errors"]["period_rel_error"] < 0.01 for r in mj)


def test_repeats_keep_one_row_per_setting_with_the_median_cost(tmp_path):
    path = tmp_path / "accuracy.json"
    main(["--scenarios", "bouncing_ball", "spring", "--settings", "dt=1/30 sub=1", "--duration-scale", "0.05",
          "--no-mujoco", "--no-plot", "--json", str(path), "--out-dir", str(tmp_path)])
    rows = json.loads(path.read_text())
    keys = [(r["scenario"], r["settings"]["label"]) for r in rows]
    assert len(keys) == len(set(keys))
    assert {r["scenario"]: r["repeats"] for r in rows} == {"bouncing_ball": 5, "spring": 1}
    main(["--scenarios", "spring", "--settings", "dt=1/30 sub=1", "--duration-scale", "0.05", "--repeats", "2",
          "--no-mujoco", "--no-plot", "--json", str(path), "--out-dir", str(tmp_path)])
    rows = json.loads(path.read_text())
    assert {r["repeats"] for r in rows} == {2} and all(r["wall_s_per_sim_s"] > 0 for r in rows)
    assert "spring 2 times" in (tmp_path / "accuracy.md").read_text()
    with pytest.raises(SystemExit):
        main(["--repeats", "0"])


def _row(scenario, label, error, cost, solver="soft_step", thesis=False, engine=None):
    settings = {"label": label, "solver": solver, "thesis_baseline": thesis}
    if engine:
        settings["engine"] = engine
    return {"scenario": scenario, "settings": settings, "errors": {PRIMARY[scenario]: error}, "wall_s_per_sim_s": cost}


def test_thesis_dominance_takes_the_cheapest_setting_that_costs_no_more_and_errs_less():
    rows = [_row("pendulum", "thesis a", 0.1, 1.0, "thesis", True),
            _row("pendulum", "thesis b", 0.001, 0.5, "thesis", True),
            _row("pendulum", "cheap", 0.05, 0.2),
            _row("pendulum", "tie", 0.1, 0.9),            # same error: not lower
            _row("pendulum", "accurate", 0.0001, 1.0),   # same cost: allowed
            _row("pendulum", "mujoco", 1e-9, 0.001, "mujoco", engine="mujoco"),  # not this engine
            _row("pendulum", "failed", None, 0.1)]
    found = {t["settings"]["label"]: d and d["settings"]["label"] for _, t, d in thesis_dominance(rows)}
    assert found == {"thesis a": "cheap", "thesis b": None}
    md = "\n".join(dominance_lines(rows))
    assert "1 of 2 thesis points are dominated" in md and "not dominated" in md
    assert dominance_lines([_row("spring", "default", 0.1, 1.0)]) == []
