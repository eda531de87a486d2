"""Calibrating the arm from bare-arm traffic: it recovers a simulated arm's known departure
(friction, offsets, the excited base parameters), refuses unexciting traffic, warns of a
payload, and ``iem calibrate`` writes an arm file from a CAN log."""

import numpy as np
import pytest

from deploy.calibrate import record_rollout
from deploy.cli import main
from iem.errors import ModelFileError
from sim.arm import ArmParams, load_arm, save_arm
from sim.calibration import (
    CalibrationError,
    _regressors,
    base_basis,
    calibrate,
    link_prior_std,
    prepare,
)
from sim.calibration import CalibrationSettings as Settings
from sim.family import default_test_payload
from sim.paths import Q0, calibration_path, excitation_path, linear_path, rest_path
from sim.plant import PandaPlant, RealityGap
from sim.robot import PandaModel, nominal_link_params

GAP = RealityGap(seed=3)


@pytest.fixture(scope="module")
def bare():
    plant = PandaPlant(gap=GAP, seed=101)  # noise seed of its own
    return plant, plant.follow(calibration_path())


@pytest.fixture(scope="module")
def arm(bare):
    _, r = bare
    return calibrate(r.t, r.q, r.dq, r.tau)


def test_recovers_friction_and_offsets(bare, arm):
    truth = bare[0].arm
    np.testing.assert_allclose(arm.offset, truth.offset, atol=0.01)  # N·m
    np.testing.assert_allclose(arm.friction[:, 0], truth.friction[:, 0], rtol=0.02)
    np.testing.assert_allclose(arm.friction[:, 1], truth.friction[:, 1], rtol=0.05)
    np.testing.assert_allclose(arm.friction[:, 2], truth.friction[:, 2], atol=0.006)  # rad/s


def test_recovers_the_excited_base_parameters(bare, arm):
    truth = bare[0].arm
    nominal = nominal_link_params().ravel()
    sd = link_prior_std(nominal, Settings())
    basis = np.linalg.qr(base_basis(PandaModel().model) / sd[:, None])[0]
    # the excited base directions: where the recorded motion tells 100 times more than the
    # prior (prior-scaled units, eigenvectors of the data's information)
    _, r = bare
    _t, q, dq, ddq, _tau = prepare(r.t, r.q, r.dq, r.tau)
    A = _regressors(PandaModel().model, q, dq, ddq).reshape(-1, 70) @ (sd[:, None] * basis)
    lam, vec = np.linalg.eigh(A.T @ A / Settings().sigma_tau ** 2)
    excited = vec[:, lam > 100.0]
    assert excited.shape[1] >= 20  # of 43 (the others stay near their prior)
    err = excited.T @ basis.T @ ((arm.link_params.ravel() - truth.link_params.ravel()) / sd)
    gap = excited.T @ basis.T @ ((nominal - truth.link_params.ravel()) / sd)
    # measured: error at most 0.28 prior standard deviations along any of them, where the
    # arm departs by up to about 1 (the rest is the filtering's bias, not noise)
    assert np.abs(err).max() < 0.4
    assert np.linalg.norm(err) < 0.5 * np.linalg.norm(gap)
    # and the arm model predicts the true arm's torques on a motion it never saw
    path = excitation_path(20.0, seed=4)
    true_model, cal_model, nom_model = (PandaModel(arm=a) for a in (truth, arm, None))
    ks = range(0, len(path), 20)
    diff = np.array([cal_model.rnea(path.q[k], path.dq[k], path.ddq[k])
                     - true_model.rnea(path.q[k], path.dq[k], path.ddq[k]) for k in ks])
    nom = np.array([nom_model.rnea(path.q[k], path.dq[k], path.ddq[k])
                    - true_model.rnea(path.q[k], path.dq[k], path.ddq[k]) for k in ks])
    rms, rms_nominal = np.sqrt((diff ** 2).mean(0)), np.sqrt((nom ** 2).mean(0))
    assert np.all(rms < 0.03), rms  # N·m
    assert np.all(rms < 0.25 * rms_nominal)


def test_report_and_consistency(arm):
    r = arm.report
    assert r["base_parameters"] == 43
    assert 1 < r["condition_number"] < 2000
    assert np.all(np.array(r["rms_after"]) < 0.2 * np.array(r["rms_before"]))
    assert r["warnings"] == []
    for p in arm.link_params:  # every body physically consistent
        from sim.calibration import _pseudo_min_eig

        assert _pseudo_min_eig(p) > 0


def test_refuses_traffic_that_does_not_excite():
    q1 = np.array(Q0)
    q1[:3] += 0.9
    path = rest_path(Q0, 1.0).then(linear_path(Q0, q1, 4.0)).then(
        linear_path(q1, Q0, 4.0)).then(rest_path(Q0, 1.0))
    r = PandaPlant(gap=GAP, seed=5).follow(path)
    with pytest.raises(CalibrationError) as err:
        calibrate(r.t, r.q, r.dq, r.tau)
    text = str(err.value)
    for j in (4, 5, 6, 7):
        assert f"joint {j} (range" in text
    assert "joint 1 (range" not in text  # it moved both ways, far enough
    with pytest.raises(CalibrationError, match="too short"):
        calibrate(r.t[:1500], r.q[:1500], r.dq[:1500], r.tau[:1500])


def test_warns_when_a_payload_is_mounted():
    r = PandaPlant(gap=GAP, seed=7, payload=default_test_payload()).follow(calibration_path())
    arm = calibrate(r.t, r.q, r.dq, r.tau)
    assert any("payload" in w for w in arm.report["warnings"])


def test_arm_file_round_trip_and_corruption(arm, tmp_path):
    path = tmp_path / "arm.msgpack"
    save_arm(arm, path)
    back = load_arm(path)
    assert isinstance(back, ArmParams) and back.crc32 == arm.crc32
    np.testing.assert_array_equal(back.link_params, arm.link_params)
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF
    path.write_bytes(bytes(data))
    with pytest.raises(ModelFileError, match="arm file"):
        load_arm(path)


def test_cli_calibrates_from_a_can_log(bare, tmp_path, capsys):
    log_file = tmp_path / "bare.blf"
    record_rollout(bare[1], log_file)
    out = tmp_path / "arm.msgpack"
    assert main(["calibrate", str(log_file), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "condition number" in text and "joint 7:" in text
    arm = load_arm(out)
    np.testing.assert_allclose(arm.offset, bare[0].arm.offset, atol=0.015)
    assert main(["calibrate", "--out", str(out)]) == 2  # nothing to calibrate from


def test_cli_writes_the_calibration_motion(tmp_path):
    from sim.paths import load_path_csv

    out = tmp_path / "motion.csv"
    assert main(["calibrate", "--write-motion", str(out)]) == 0
    back = load_path_csv(out)
    np.testing.assert_allclose(back.q, calibration_path().q, atol=1e-6)


def test_calibrates_from_a_live_link():
    """The simulated controller (nominal plant: no friction, no offsets) plays the
    calibration motion on the virtual bus; the live link's joint states calibrate the arm."""
    from deploy.calibrate import calibrate_sources
    from firmware_bridge.links import open_link
    from firmware_bridge.sim_controller import SimController, open_port

    channel = "iem-test-live-calibration"
    link = open_link("virtual", channel, profile="fd", silence_timeout=5.0)
    port, _ = open_port("virtual", channel, "fd")
    controller = SimController(port, path=calibration_path(), realtime=False, once=True)
    try:
        controller.start()
        arm = calibrate_sources(link=link, duration=12.0)
    finally:
        controller.stop()
        port.close()
    assert arm.report["duration_s"] > 10.0
    np.testing.assert_allclose(arm.offset, 0.0, atol=0.01)
    after = np.array(arm.report["rms_after"])
    assert np.all(after < 0.03)
