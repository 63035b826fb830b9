import json
import math

import numba
import pytest

from benchmarks.throughput import DEFAULT_THREADS, main

KEYS = {"engine", "mode", "scene", "worlds", "dt_s", "world_steps_per_s", "sim_s_per_s", "bytes_per_world", "threads"}
CORES = numba.config.NUMBA_NUM_THREADS
MODES = {*(f"batched-{t}thr" for t in range(1, CORES + 1)), "loop", "loop-rk4", "loop-implicitfast", "rollout-rk4-1thread",
         "rollout-rk4-2thread", "rollout-implicitfast-1thread", "rollout-implicitfast-2thread", "env", "vector-env",
         "cold-compile", "warm-start"}


def check_rows(rows):
    assert isinstance(rows, list) and rows
    for r in rows:
        assert KEYS <= r.keys()
        assert r["engine"] in ("ragdoll", "mujoco", "pybullet")
        assert r["mode"] in MODES
        if r["mode"].startswith("batched"):
            assert r["mode"] == f"batched-{r['threads']}thr"
        assert isinstance(r["worlds"], int) and r["worlds"] >= 1
        if r["mode"] in ("cold-compile", "warm-start"):
            assert math.isfinite(r["seconds"]) and r["seconds"] > 0
            continue
        assert math.isfinite(r["world_steps_per_s"]) and r["world_steps_per_s"] > 0
        for key in ("dt_s", "sim_s_per_s", "bytes_per_world"):
            assert r[key] is None or (math.isfinite(r[key]) and r[key] > 0)


def test_quick_run_writes_rows(tmp_path, capsys):
    path = tmp_path / "throughput.json"
    main(["--quick", "--json", str(path)])
    rows = json.loads(path.read_text())
    check_rows(rows)
    scenes = {r["scene"] for r in rows}
    assert {"free_bodies", "ragdoll_air"} <= scenes
    # 1 thread and all cores at W = 8 (SERIAL_BELOW, the prange path), one thread at W = 1 (stepped serially)
    assert DEFAULT_THREADS == tuple(sorted({1, CORES}))
    for scene in scenes:
        assert sorted((r["worlds"], r["threads"]) for r in rows if r["scene"] == scene) == [
            (1, 1)] + [(8, t) for t in DEFAULT_THREADS]
    for r in rows:
        assert r["engine"] == "ragdoll" and r["mode"] == f"batched-{r['threads']}thr" and r["worlds"] in (1, 8)
        assert r["bytes_per_world"] > 0 and r["sim_s_per_s"] > 0
    assert "world-steps/s" in capsys.readouterr().out


def test_quick_mujoco_comparison(tmp_path):
    pytest.importorskip("mujoco")
    pytest.importorskip("gymnasium")
    path = tmp_path / "throughput.json"
    main(["--quick", "--scenes", "ragdoll_air", "--worlds", "1", "--compare-mujoco", "--json", str(path)])
    rows = json.loads(path.read_text())
    check_rows(rows)
    modes = {(r["engine"], r["mode"]) for r in rows}
    assert {("mujoco", f"{kind}-{integrator}{threads}") for integrator in ("rk4", "implicitfast")
            for kind, threads in (("loop", ""), ("rollout", "-1thread"), ("rollout", "-2thread"))} <= modes
    assert {("mujoco", "env"), ("mujoco", "vector-env"), ("ragdoll", "batched-1thr")} <= modes
    assert {r["scene"] for r in rows if r["mode"] == "env"} >= {"Humanoid-v5", "InvertedPendulum-v5"}
    # Timed lying on the ground, as the ragdoll is: a fallen humanoid touches it at several points.
    for r in rows:
        if r["engine"] == "mujoco" and r["mode"].startswith(("loop", "rollout")):
            assert r["scene"] == "humanoid_ground" and r["contacts_per_world"] >= 2


@pytest.mark.skipif(CORES < 2, reason="needs 2 threads")
def test_quick_run_on_two_threads(tmp_path):
    import engine

    before = engine.get_threads()
    path = tmp_path / "throughput.json"
    main(["--quick", "--scenes", "ragdoll_ground", "--worlds", "1", "4", "16", "--threads", "2", "--json", str(path)])
    rows = json.loads(path.read_text())
    check_rows(rows)
    # W below SERIAL_BELOW (8) steps on the calling thread whatever the count: one row each, at the smallest T.
    assert sorted((r["mode"], r["worlds"], r["threads"]) for r in rows) == [
        ("batched-2thr", 1, 2), ("batched-2thr", 4, 2), ("batched-2thr", 16, 2)]
    assert engine.get_threads() == before  # the benchmark restores the thread count
