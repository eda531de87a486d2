"""``iem bench paper --quick`` writes results.json in the issue's schema, and the report."""

import json

import pytest

from deploy.bench.paper import QUICK_PACED_POINTS, run_paper
from deploy.bench.report import PAPER_TABLE2

GROUPS = {"mass", "com", "inertia"}


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    out = tmp_path_factory.mktemp("paper")
    run_paper(out, quick=True, seed=0, log=lambda *a: None)
    return out, json.loads((out / "results.json").read_text())


def test_schema(results):
    _, r = results
    assert r["params"] == ["m", "mrx", "mry", "mrz", "Ixx", "Ixy", "Ixz", "Iyy", "Iyz", "Izz"]
    assert r["models"][:5] == ["IEM", "old_IEM", "BEM", "LS", "IEM+phys"]
    for model in r["models"]:
        exc = r["scenarios"]["excitation"][model]
        assert set(exc["mae"]) == set(r["params"]) and set(exc["mae_groups"]) == GROUPS
        new = r["scenarios"]["new_path"][model]
        assert set(new["mae_groups"]) == GROUPS and set(new["convergence_s"]) == GROUPS
    for model in ("IEM", "old_IEM", "IEM+phys"):
        f = r["scenarios"]["forgetting"][model]
        assert set(f["before"]) == GROUPS and set(f["after"]) == GROUPS
    t = r["timing"]
    assert set(t["route_us_median"]) == {"1", "10", "100", "1000", "10000"}
    assert t["predict_us_median"] > 0 and t["learn_ms_per_point_median"] > 0
    # the cycle as the plug-in runs it (training in the worker) beside the inline figure
    assert 0 < t["phys_cycle_us_median"] <= t["phys_cycle_us_p99"]
    assert 0 < t["phys_cycle_paced_us_median"] <= t["phys_cycle_paced_us_p99"]
    assert t["phys_cycle_cpu_us_mean"] > 0 and t["phys_cycle_paced_cpu_us_mean"] > 0
    # back to back over the whole new path; paced (10 ms of wall time a point) over its start
    assert t["phys_cycle_points"] > t["phys_cycle_paced_points"] == QUICK_PACED_POINTS
    assert t["phys_us_per_sample_median"] > 0
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


def test_forgetting_beside_the_papers_old_iem(results):
    """The old IEM's forgetting with the paper's figures (Table 2 before, 5.3 after), raw
    beside smoothed, and the running-centre variant kept for comparison, which forgets more."""
    out, r = results
    old = r["scenarios"]["forgetting"]["old_IEM"]
    assert old["update"] == "frozen"
    paper, table2 = old["paper"], PAPER_TABLE2["old_IEM"]  # Table 2 per group, 5.3, ratio
    assert paper["before"] == pytest.approx({"mass": table2[0], "com": sum(table2[1:4]) / 3,
                                             "inertia": sum(table2[4:]) / 6}, rel=1e-12)
    for g in GROUPS:
        assert paper["ratio"][g] == pytest.approx(paper["after"][g] / paper["before"][g],
                                                  rel=1e-12)
    for key in ("before_raw", "after_raw"):
        assert set(old[key]) == GROUPS
    variant = old["variants"]["running_centre"]
    assert variant["before"] == old["before"]  # the same learners before the update
    assert set(variant["new_path"]) == GROUPS
    assert variant["after"]["mass"] > old["after"]["mass"]
    text = (out / "report.md").read_text()
    assert "paper after (5.3)" in text and "old_IEM (running_centre)" in text
    assert "times the paper's figures" in text
    for g in GROUPS:  # the paper's after/before beside ours
        assert f"{paper['ratio'][g]:.3g} |" in text


def test_checks_that_can_fail(results):
    """Forgetting by the weights (the old IEM's change, the IEM's stay bit-identical, even
    after learning inside the excitation bags on the revisit), raw beside smoothed for every
    scenario, and hold-out payloads drawn at random outside the 77."""
    _, r = results
    sc = r["scenarios"]
    assert sc["forgetting"]["IEM"]["weights_identical"] is True
    assert sc["forgetting"]["IEM+phys"]["weights_identical"] is True
    assert sc["forgetting"]["old_IEM"]["weights_identical"] is False
    assert sc["revisit"]["IEM"]["weights_identical"] is True
    assert sc["revisit"]["old_IEM"]["weights_identical"] is False
    for scenario in ("excitation", "new_path"):
        for model in r["models"]:
            assert set(sc[scenario][model]["mae_groups_raw"]) == GROUPS
    from deploy.bench.honesty import holdout_payloads
    from sim.family import training_payloads

    names = [p.name for p in holdout_payloads(0, 2)]
    assert set(sc["holdout"]["IEM+phys"]) >= set(names)
    assert {"mean_mae_groups", "max_mae_groups_raw"} <= set(sc["holdout"]["IEM"])
    trained = {tuple(p.to_phi().round(12)) for p in training_payloads()}
    assert not any(tuple(p.to_phi().round(12)) in trained for p in holdout_payloads(0, 4))


@pytest.mark.smoke
def test_report_and_figures(results):
    out, _ = results
    text = (out / "report.md").read_text()
    for heading in ("Table 2", "Table 4", "Forgetting", "Timing", "uncertainty", "hold-out",
                    "payload carried over", "payload change"):
        assert heading in text
    for fig in ("fig5_forgetting.png", "fig6_new_path_error.png", "bags.png",
                "payload_change.png"):
        assert (out / fig).stat().st_size > 1000


def test_schema_beyond_the_paper(results):
    _, r = results
    new = r["scenarios"]["new_path"]
    for model in r["models"]:
        assert set(new[model]["mae_groups_raw"]) == GROUPS
        assert 0.0 <= new[model]["consistent_share"] <= 1.0
        reports_std = model in ("LS", "IEM+phys")
        assert (new[model]["coverage_2sigma"] is not None) == reports_std
        if reports_std:
            assert 0.0 <= new[model]["coverage_2sigma"] <= 1.0
            assert set(new[model]["coverage_2sigma_groups"]) == GROUPS
            assert set(new[model]["mean_std_groups"]) == GROUPS
    change = r["scenarios"]["payload_change"]
    assert set(change) == set(r["models"])
    for model, c in change.items():
        assert set(c["mae_groups"]) == GROUPS
        assert (c["detect_s"] is None) == (model != "IEM+phys")
        assert (c["false_alarms"] is None) == (model != "IEM+phys")
    assert r["setup"]["change"] == {"from": "test-3w", "to": "test-4w", "at_s": 3.0}


def test_iem_phys_meets_its_bar_even_in_the_quick_run(results):
    """The issue's figures that do not depend on the training size (see the closing note
    for the accuracy targets)."""
    _, r = results
    s = r["scenarios"]
    new = s["new_path"]["IEM+phys"]
    assert all(v is not None and v <= 0.5 for v in new["convergence_s"].values())
    assert new["coverage_2sigma"] >= 0.9
    assert new["consistent_share"] == 1.0  # every one of its 6000 estimates
    for g in GROUPS:  # better than the paper's IEM everywhere, far better than our IEM
        assert new["mae_groups"][g] < s["new_path"]["IEM"]["mae_groups"][g] * 1.2
    assert new["mae_groups_raw"]["mass"] < 0.1 * s["new_path"]["IEM"]["mae_groups_raw"]["mass"]
    change = s["payload_change"]["IEM+phys"]
    assert change["detect_s"] is not None and change["detect_s"] <= 0.2
    assert change["false_alarms"] == 0
    for scenario in ("excitation", "new_path"):  # fixed payload: no false alarm
        assert s[scenario]["IEM+phys"]["changes"] == 0
    assert s["forgetting"]["IEM+phys"]["changes_after"] == 0
    f = s["forgetting"]["IEM+phys"]
    for g in GROUPS:
        assert f["after"][g] <= 1.05 * f["before"][g]
    assert change["mae_groups"]["mass"] < 0.5 * s["payload_change"]["IEM"]["mae_groups"]["mass"]


def test_the_payload_carried_over_to_the_new_path(results):
    """new_path_continued: the models with a payload state keep it from the excitation path
    (same payload, no change detected) and end up more accurate than afresh."""
    _, r = results
    cont, fresh = r["scenarios"]["new_path_continued"], r["scenarios"]["new_path"]
    assert set(cont) == {"LS", "IEM+phys"}
    for c in cont.values():
        assert set(c["mae_groups"]) == GROUPS and set(c["convergence_s"]) == GROUPS
        assert c["coverage_2sigma"] is not None
    phys = cont["IEM+phys"]
    for c in (phys, fresh["IEM+phys"]):  # what the data alone told, per parameter
        assert set(c["data_std_end"]) == set(r["params"])
    # the excitation path's equations carried over see the payload far better
    assert phys["data_std_end"]["Ixz"] < fresh["IEM+phys"]["data_std_end"]["Ixz"]
    assert phys["changes"] == 0  # the restart of the stream is not taken for a new payload
    for g in GROUPS:
        assert phys["mae_groups"][g] < fresh["IEM+phys"]["mae_groups"][g]
    assert cont["LS"]["mae_groups"]["mass"] < fresh["LS"]["mae_groups"]["mass"]
