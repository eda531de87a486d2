"""``iem bench paper --quick`` writes results.json in the issue's schema, and the report."""

import json

import pytest

from iem.bench.paper import run_paper

GROUPS = {"mass", "com", "inertia"}


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    out = tmp_path_factory.mktemp("paper")
    run_paper(out, quick=True, seed=0, log=lambda *a: None)
    return out, json.loads((out / "results.json").read_text())


def test_schema(results):
    _, r = results
    assert r["params"] == ["m", "mrx", "mry", "mrz", "Ixx", "Ixy", "Ixz", "Iyy", "Iyz", "Izz"]
    assert r["models"][:4] == ["IEM", "old_IEM", "BEM", "LS"]
    for model in r["models"]:
        exc = r["scenarios"]["excitation"][model]
        assert set(exc["mae"]) == set(r["params"]) and set(exc["mae_groups"]) == GROUPS
        new = r["scenarios"]["new_path"][model]
        assert set(new["mae_groups"]) == GROUPS and set(new["convergence_s"]) == GROUPS
    for model in ("IEM", "old_IEM"):
        f = r["scenarios"]["forgetting"][model]
        assert set(f["before"]) == GROUPS and set(f["after"]) == GROUPS
    t = r["timing"]
    assert set(t["route_us_median"]) == {"1", "10", "100", "1000", "10000"}
    assert t["predict_us_median"] > 0 and t["learn_ms_per_point_median"] > 0
    assert r["bags"]["after_excitation"] >= 3
    assert r["bags"]["after_new_path"] > r["bags"]["after_excitation"]


def test_the_paper_story_holds_even_in_the_quick_run(results):
    _, r = results
    new = r["scenarios"]["new_path"]
    assert new["BEM"]["mae_groups"]["mass"] > 10 * new["IEM"]["mae_groups"]["mass"]
    forget = r["scenarios"]["forgetting"]
    for g in GROUPS:
        assert forget["IEM"]["after"][g] <= 1.05 * forget["IEM"]["before"][g]
    assert forget["old_IEM"]["after"]["mass"] >= 2 * forget["old_IEM"]["before"]["mass"]


def test_report_and_figures(results):
    out, _ = results
    text = (out / "report.md").read_text()
    for heading in ("Table 2", "Table 4", "Forgetting", "Timing"):
        assert heading in text
    for fig in ("fig5_forgetting.png", "fig6_new_path_error.png", "bags.png"):
        assert (out / fig).stat().st_size > 1000
