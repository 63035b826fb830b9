import json
import math

from benchmarks.effects import EFFECTS, main


def test_quick_run_writes_rows(tmp_path):
    path = tmp_path / "effects.json"
    md = tmp_path / "effects.md"
    main(["--quick", "--worlds", "1", "--steps", "2", "--repeats", "1", "--json", str(path),
          "--markdown", str(md)])
    rows = json.loads(path.read_text())
    assert isinstance(rows, list) and rows
    for r in rows:
        assert {"scene", "effects", "step_s", "worlds", "effect_names", "variant"} <= r.keys()
        assert set(r["effects"]) == set(EFFECTS) and all(isinstance(v, bool) for v in r["effects"].values())
        assert r["worlds"] == 1 and math.isfinite(r["step_s"]) and r["step_s"] > 0
    assert {r["scene"] for r in rows} == {"inverted_pendulum", "ragdoll_ground", "ragdoll_air", "box_pile"}
    by = {(r["scene"], r["variant"]): r for r in rows}
    # Switching an effect off at build time compiles the same step as building without it.
    assert by["ragdoll_ground", "gravity disabled"]["effect_names"] == \
        by["ragdoll_ground", "no gravity (gravity=None)"]["effect_names"]
    assert "contacts" not in by["ragdoll_ground", "contacts disabled"]["effect_names"]
    assert "contacts" not in by["inverted_pendulum", "baseline"]["effect_names"]
    assert "friction" not in by["box_pile", "friction disabled"]["effect_names"]
    assert "self_collision" in by["ragdoll_ground", "+ self_collision"]["effect_names"]
    assert "gravitation" in by["box_pile", "+ gravitation"]["effect_names"]
    assert "damping" not in by["ragdoll_ground", "+ damping, disabled"]["effect_names"]
    assert "effect_names" in md.read_text()
