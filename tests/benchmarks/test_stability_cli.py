"""Smoke test of ``python -m benchmarks.stability``: it runs, writes its rows,
and ``--settings`` reaches the cases' models."""

from __future__ import annotations

import json

import pytest

from benchmarks import stability


def test_stability_cli_writes_rows_and_applies_settings(tmp_path, monkeypatch):
    seen = []
    real = stability.run_case

    def spy(case, **kw):
        seen.append(case.model.settings.substeps)
        return real(case, steps=3)

    monkeypatch.setattr(stability, "run_case", spy)
    path = tmp_path / "rows.json"
    assert stability.main(["--quick", "--case", "mass_ratio_stack", "--settings", '{"substeps": 2}',
                           "--json", str(path)]) == 0
    rows = json.loads(path.read_text())
    assert seen == [2]
    assert [r["name"] for r in rows] == ["mass_ratio_stack"]
    assert rows[0]["steps"] == 3 and rows[0]["nan"] is False


def test_stability_cli_rejects_unknown_case():
    with pytest.raises(SystemExit):
        stability.main(["--case", "no_such_case"])
