"""The plug-in on a real Panda's recording (``../shared/real``, GPL-3.0, read from there).

Calibrated on the first half, held out on the second: the bare arm, a known payload's exact
torque added to the real torque, the safety gate's decisions, and the wrong end effector.
Skipped, with the reason, where the recording is not there."""

import numpy as np
import pytest

from deploy.bench.real import default_dir, load_recording, run_real
from iem.errors import InvalidInputError


@pytest.fixture(scope="module")
def real_dir():
    try:
        load_recording()
    except InvalidInputError as exc:
        pytest.skip(f"the real recording is not here ({exc}); set IEM_REAL_DIR to run these")
    return default_dir()


@pytest.fixture(scope="module")
def held_out(real_dir, tmp_path_factory):
    return run_real(tmp_path_factory.mktemp("real"), real_dir, cases=("bare", "test-3w"),
                    log=lambda *a: None)


def test_calibration_explains_the_real_arm_and_measures_its_noise(held_out):
    cal = held_out["calibration"]
    assert np.all(np.array(cal["rms_after"]) <= np.array(cal["rms_before"]))
    noise = cal["noise"]
    # the arm's own noise, far above the sensor model's 0.01-0.02 N·m
    assert min(noise["std"]) > 0.03 and max(noise["std"]) < 1.0
    assert noise["bias_std"][0] > 0.0


def test_held_out_bare_arm_reads_no_payload(held_out):
    bare = held_out["cases"]["bare"]
    assert abs(bare["final_mass"]) <= 0.02
    assert bare["arm_mismatch"] is None
    assert bare["coverage_2sigma"]["mass"] >= 0.9


def test_a_known_payload_is_identified_with_honest_uncertainty(held_out):
    case = held_out["cases"]["test-3w"]
    assert abs(case["final_mass"] - 1.615) <= 0.03
    assert case["mae_groups"]["com"] <= 0.01
    for group, share in case["coverage_2sigma"].items():
        assert share >= 0.9, group


def test_the_gate_writes_a_load_that_helps_and_nothing_wrong(held_out):
    """A 1.6 kg payload's exact torque added to the real arm (semi-synthetic): the controller
    at 0 kg is written, within 0.05 kg and 10 mm of the truth; the bare arm with the
    controller at 0 kg is never written."""
    assert held_out["cases"]["bare"]["would_send"] == 0
    case = held_out["cases"]["test-3w"]
    assert case["would_send"] >= 1, case["gate"]
    assert case["max_write_mass_error"] <= 0.05
    assert case["max_write_com_error_m"] <= 0.010


def test_the_wrong_end_effector_is_named(real_dir, tmp_path):
    """The bare real arm through the nominal model with the hand: the default model (IEM+phys)
    keeps its estimate a possible body, but its mass before that projection reads below zero,
    and the replay says the arm model does not match the arm."""
    from deploy.bench.real import write_csv
    from deploy.replay.core import replay

    t, q, dq, tau = load_recording(real_dir)
    keep = t >= t[-1] - 6.0
    path = tmp_path / "bare.csv"
    write_csv(path, t[keep], q[keep], dq[keep], tau[keep])
    summary, _ = replay(path, log=lambda *a: None)
    assert summary["model"] == "IEM+phys"
    assert summary["arm_mismatch"] is not None, summary["gate"]
    assert summary["arm_mismatch"]["mass_kg"] < -0.1
    assert "end effector" in summary["arm_mismatch"]["message"]
