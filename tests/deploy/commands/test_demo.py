"""``iem demo`` end to end (real time, about 40 s: marked slow; ``make demo`` runs it)."""

import json

import pytest

from deploy.commands.demo import run_demo


@pytest.mark.slow
@pytest.mark.hil
def test_demo_identifies_and_writes_back(tmp_path):
    summary = run_demo(tmp_path / "demo", status=False, log=lambda *a: None,
                       json_path=tmp_path / "summary.json")
    assert json.loads((tmp_path / "summary.json").read_text())["bags"] == summary["bags"]
    for key in ("mae_groups", "bags", "estimates", "latency_us", "writes", "frames"):
        assert key in summary
    new_task = summary["mae_groups_by_phase"]["new task"]
    assert new_task["mass"] < 0.01 and new_task["com"] < 0.005
    assert summary["writes"]["sent"] >= 1 and summary["writes"]["acked"] >= 1
    assert summary["frames"]["lost"] == 0
    for name in ("summary.json", "error.png", "bags.png"):
        assert (tmp_path / "demo" / name).stat().st_size > 100
