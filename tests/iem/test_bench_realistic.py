"""``iem bench realistic --quick``: the schema of results.json, the report, and the story:
calibration explains the arm's torques and makes the calibrated models better."""

import json

import pytest

from deploy.cli import main
from iem.bench.realistic import BATCH_MODELS, MODEL_ORDER, SCENARIOS

GROUP_KEYS = {"mass", "com", "inertia"}


@pytest.fixture(scope="module")
def out(tmp_path_factory):
    out = tmp_path_factory.mktemp("realistic")
    assert main(["bench", "realistic", "--out", str(out), "--quick", "--seed", "0"]) == 0
    return out


@pytest.fixture(scope="module")
def results(out):
    return json.loads((out / "results.json").read_text())


def test_schema(results):
    assert results["models"] == [*MODEL_ORDER, *BATCH_MODELS]
    assert set(results["scenarios"]) == set(SCENARIOS)
    for scenario in SCENARIOS:
        for model in MODEL_ORDER:
            s = results["scenarios"][scenario][model]
            assert set(s["mae_groups"]) == GROUP_KEYS
            assert set(s["mae_groups_raw"]) == GROUP_KEYS
            physics = "phys" in model
            assert (s["coverage_2sigma"] is None) != physics
            assert (s["coverage_2sigma_groups"] is None) != physics
            if physics:
                assert set(s["coverage_2sigma_groups"]) == GROUP_KEYS
                assert isinstance(s["false_alarms"], int)
            else:
                assert s["false_alarms"] is None
    for scenario in SCENARIOS:  # the offline identification beside the online models
        for model in BATCH_MODELS:
            s = results["scenarios"][scenario][model]
            if s["mae_groups"] is None:
                assert s["refused"]  # e.g. bare_arm: no payload between the recordings
                continue
            assert set(s["mae_groups"]) == GROUP_KEYS and s["false_alarms"] is None
            assert set(s["coverage_2sigma_groups"]) == GROUP_KEYS
    assert results["scenarios"]["bare_arm"]["batch+bare"]["refused"]
    batch = results["scenarios"]["new_path"]["batch+bare"]["mae_groups"]
    assert batch["mass"] < 0.005  # a bare recording of the same motion cancels the arm
    assert results["setup"]["gap"]["seed"] == 1000  # never a tuning seed
    assert results["setup"]["calibration_noise_seed"] == 500


def test_calibration_explains_the_arm(results):
    cal = results["calibration"]
    before, after = cal["report"]["rms_before"], cal["report"]["rms_after"]
    assert all(a < 0.25 * b for a, b in zip(after, before, strict=True))
    held = cal["held_out"]
    for nom, c, true in zip(held["rms_nominal"], held["rms_calibrated"], held["rms_true_arm"],
                            strict=True):
        assert c < 0.25 * nom and c < true + 0.01  # N·m: at the true arm's floor


def test_calibrated_models_do_better(results):
    sc = results["scenarios"]
    for scenario in ("new_path", "light_tool", "payload_change"):
        assert (sc[scenario]["IEM+phys+cal"]["mae_groups"]["mass"]
                < 0.5 * sc[scenario]["IEM+phys"]["mae_groups"]["mass"])
    assert (sc["new_path"]["IEM+cal"]["mae_groups"]["mass"]
            < 0.5 * sc["new_path"]["IEM"]["mae_groups"]["mass"])


def test_report(out, results):
    text = (out / "report.md").read_text()
    for scenario in SCENARIOS:
        assert f"## {scenario}" in text
    assert "## Targets (issues 11 and 16)" in text and "held out" in text
    assert (out / "arm.msgpack").is_file()
