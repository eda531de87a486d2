"""Calibrating the arm from bare-arm traffic: it recovers a simulated arm's known departure
(friction, offsets, the excited base parameters), never fits a joint worse than the nominal
model (a viscous arm, a broken fit, the real recording), filters by the time stamps, refuses
unexciting traffic, warns of a payload, and ``iem calibrate`` writes an arm file from a CAN
log."""

import numpy as np
import pytest

from deploy.cli import main
from iem.errors import ModelFileError
from sim.arm import ArmParams, load_arm, save_arm
from sim.calibration import (
    CalibrationError,
    base_basis,
    calibrate,
    calibrate_segments,
    calibration_signals,
    link_prior_std,
    never_worse,
)
from sim.calibration import CalibrationSettings as Settings
from sim.calibration.excitation import regressors
from sim.family import default_test_payload
from sim.friction import friction_torque
from sim.paths import Q0, calibration_path, excitation_path, linear_path, rest_path
from sim.plant import ArmPlant, RealityGap
from sim.robot import ArmModel, nominal_link_params
from tests.real_data import real_recording

GAP = RealityGap(seed=3).modelled_only()
"""Links, friction (Coulomb, viscous, Stribeck, per direction) and offsets: all the arm
model describes, so that what the calibration recovers can be checked against the truth."""


def prepare(t, q, dq, tau):
    """``(t, q, dq, ddq, tau)`` of one recording as the calibration prepares it."""
    (p,) = calibration_signals([(t, q, dq, tau)])
    return p.t, p.q, p.dq, p.ddq, p.tau


@pytest.fixture(scope="module")
def bare(bare_calibration_run):
    """``(plant, rollout)``: the calibration motion on the plant of ``GAP``, noise seed 101
    (tests/conftest.py's, which test_arm.py's arm file is calibrated from too)."""
    assert bare_calibration_run[0].gap == GAP
    return bare_calibration_run


@pytest.fixture(scope="module")
def arm(bare):
    _, r = bare
    return calibrate(r.t, r.q, r.dq, r.tau)


def test_recovers_friction_and_offsets(bare, arm):
    truth = bare[0].arm
    np.testing.assert_allclose(arm.offset, truth.offset, atol=0.015)  # N·m
    # the friction torque over the speeds the motion reaches (measured: within 0.027 N·m;
    # the parameters trade off among themselves where the motion cannot tell them apart)
    v = np.linspace(-1.0, 1.0, 401)[:, None] * np.ones(7)
    err = friction_torque(v, arm.friction) - friction_torque(v, truth.friction)
    assert np.abs(err).max() < 0.04, np.abs(err).max(axis=0)
    assert arm.friction.shape == truth.friction.shape == (7, 9)


def test_recovers_gaz_friction_of_a_gaz_arm():
    """On an arm with Gaz's friction alone the full model finds Gaz's parameters (measured:
    phi1 within 2 %, phi2 within 3 %) and no viscous or Stribeck friction to speak of."""
    gaz = RealityGap(seed=3, viscous=0.0, stribeck=0.0).modelled_only()  # Gaz's friction alone
    plant = ArmPlant(gap=gaz, seed=101)
    r = plant.follow(calibration_path(20.0))
    arm, truth = calibrate(r.t, r.q, r.dq, r.tau), plant.arm
    np.testing.assert_allclose(arm.friction[:, 0], truth.friction[:, 0], rtol=0.04)
    np.testing.assert_allclose(arm.friction[:, 1], truth.friction[:, 1], rtol=0.06)
    v = np.linspace(-1.5, 1.5, 301)[:, None] * np.ones(7)
    assert np.abs(friction_torque(v, arm.friction) - friction_torque(v, truth.friction)).max() \
        < 0.015  # N·m (measured 0.011)


def test_recovers_the_excited_base_parameters(bare, arm):
    truth = bare[0].arm
    nominal = nominal_link_params().ravel()
    sd = link_prior_std(nominal, Settings())
    basis = np.linalg.qr(base_basis(ArmModel().model) / sd[:, None])[0]
    # the excited base directions: where the recorded motion tells 100 times more than the
    # prior (prior-scaled units, eigenvectors of the data's information)
    _, r = bare
    _t, q, dq, ddq, _tau = prepare(r.t, r.q, r.dq, r.tau)
    A = regressors(ArmModel().model, q, dq, ddq).reshape(-1, 70) @ (sd[:, None] * basis)
    lam, vec = np.linalg.eigh(A.T @ A / Settings().sigma_tau ** 2)
    excited = vec[:, lam > 100.0]
    assert excited.shape[1] >= 20  # of 43 (the others stay near their prior)
    err = excited.T @ basis.T @ ((arm.link_params.ravel() - truth.link_params.ravel()) / sd)
    gap = excited.T @ basis.T @ ((nominal - truth.link_params.ravel()) / sd)
    # measured: error at most 0.32 prior standard deviations along any of them, 0.67 in
    # norm where the arm departs by 1.3 (the rest is the filtering's bias, not noise, and
    # the viscous and Stribeck friction's share of it)
    assert np.abs(err).max() < 0.4
    assert np.linalg.norm(err) < 0.6 * np.linalg.norm(gap)
    # and the arm model predicts the true arm's torques on a motion it never saw
    path = excitation_path(20.0, seed=4)
    true_model, cal_model, nom_model = (ArmModel(arm=a) for a in (truth, arm, None))
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
    assert r["warnings"] == [] and r["fallback_joints"] == []
    assert r["iterations"] < Settings().iterations  # converged
    for p in arm.link_params:  # every body physically consistent
        from sim.calibration.consistency import pseudo_min_eig

        assert pseudo_min_eig(p) > 0


def test_refuses_traffic_that_does_not_excite():
    q1 = np.array(Q0)
    q1[:3] += 0.9
    path = rest_path(Q0, 1.0).then(linear_path(Q0, q1, 4.0)).then(
        linear_path(q1, Q0, 4.0)).then(rest_path(Q0, 1.0))
    r = ArmPlant(gap=GAP, seed=5).follow(path)
    with pytest.raises(CalibrationError) as err:
        calibrate(r.t, r.q, r.dq, r.tau)
    text = str(err.value)
    for j in (4, 5, 6, 7):
        assert f"joint {j} (range" in text
    assert "joint 1 (range" not in text  # it moved both ways, far enough
    with pytest.raises(CalibrationError, match="too short"):
        calibrate(r.t[:1500], r.q[:1500], r.dq[:1500], r.tau[:1500])


def test_warns_when_a_payload_is_mounted():
    r = ArmPlant(gap=GAP, seed=7, payload=default_test_payload()).follow(calibration_path())
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


def test_cli_calibrates_from_a_can_log(bare, calibrated_from_a_can_log, tmp_path):
    """``iem calibrate`` on ``bare``'s run written as a CAN log (tests/conftest.py runs it
    once for this test and test_arm.py)."""
    cli = calibrated_from_a_can_log
    assert cli["status"] == 0
    text = cli["printed"]
    assert "condition number" in text and "joint 7:" in text
    arm = load_arm(cli["arm"])
    np.testing.assert_allclose(arm.offset, bare[0].arm.offset, atol=0.015)
    out = tmp_path / "arm.msgpack"
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
    from deploy.commands.calibrate import calibrate_sources
    from deploy.simcell.controller import SimController
    from firmware_bridge.controller_port import open_port
    from firmware_bridge.links import open_link

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
    # 12 s: the offsets trade a little with the direction-dependent friction (measured
    # 0.018 N·m at most)
    np.testing.assert_allclose(arm.offset, 0.0, atol=0.025)
    after = np.array(arm.report["rms_after"])
    assert np.all(after < 0.03)


def test_never_worse_than_nominal_on_a_viscous_arm():
    """The issue's arm: viscous friction up to 1 N·m·s/rad per direction beside the Coulomb
    part, links and offsets off, 20 s of the calibration motion. Gaz's sigmoid alone, fitted
    by plain Gauss-Newton, left joint 5 worse than the nominal model (0.91 -> 1.03 N·m RMS)
    on this seed; the full friction model, fitted by Levenberg-Marquardt inside bounds,
    brings every joint to the noise's floor (measured 0.007-0.020 N·m)."""
    gap = RealityGap(seed=7, stribeck=0.0, viscous=1.0).modelled_only()
    r = ArmPlant(gap=gap, seed=107).follow(calibration_path(20.0))
    arm = calibrate(r.t, r.q, r.dq, r.tau)
    before, after = np.array(arm.report["rms_before"]), np.array(arm.report["rms_after"])
    assert before[4] > 0.8  # the joint the old fit made worse
    assert np.all(after <= before)
    assert np.all(after < 0.03), after
    assert arm.report["fallback_joints"] == []


def test_the_guard_undoes_a_fit_that_is_worse_than_nominal(bare, arm):
    """Handed a fit that is worse than the nominal model on some joints, the last guard
    refits those joints' friction and offsets alone and, where the bodies are to blame,
    keeps the nominal bodies: no joint ends worse, and the warnings name the joints."""
    _, r = bare
    _t, q, dq, ddq, tau = prepare(r.t, r.q, r.dq, r.tau)
    W = regressors(ArmModel().model, q, dq, ddq)
    theta0 = nominal_link_params()
    nominal = np.sqrt(np.mean((tau - W @ theta0.ravel()) ** 2, axis=0))

    def rms(params, phi, off):
        res = tau - W @ params.ravel() - friction_torque(dq, phi) - off
        return np.sqrt(np.mean(res ** 2, axis=0))

    # a friction gone astray on joint 3 and an offset on joint 6: theirs alone to fix
    phi = np.array(arm.friction)
    phi[2, 0] = 4.0
    off = np.array(arm.offset)
    off[5] += 1.0
    assert np.all(rms(arm.link_params, phi, off)[[2, 5]] > nominal[[2, 5]])
    params, phi2, off2, warnings, joints = never_worse(W, dq, tau, theta0, arm.link_params,
                                                       phi, off)
    assert joints == [3, 6] and len(warnings) == 2 and "joint 3" in warnings[0]
    np.testing.assert_array_equal(params, arm.link_params)
    assert np.all(rms(params, phi2, off2) <= nominal)
    assert np.all(rms(params, phi2, off2)[[2, 5]] < 0.05)
    # bodies gone astray (body 6 twice as heavy): the nominal bodies, friction refitted
    bad = np.array(arm.link_params)
    bad[5] *= 2.0
    params, phi3, off3, warnings, joints = never_worse(W, dq, tau, theta0, bad, arm.friction,
                                                       arm.offset)
    np.testing.assert_array_equal(params, theta0)
    assert joints and "bodies kept nominal" in warnings[-1]
    assert np.all(rms(params, phi3, off3) <= nominal)


def test_prepare_filters_by_the_time_stamps():
    """A logger's jitter (steps of 0.7-1.6 ms, a few of 9 ms, as the real recording has): the
    signals are resampled onto a uniform grid before the zero-phase filter, so ``ddq`` is
    right; filtered sample by sample it was 12 % off on the real recording."""
    rng = np.random.default_rng(0)
    dt = rng.uniform(0.7e-3, 1.6e-3, 12000)
    dt[rng.choice(12000, 40, replace=False)] = 9e-3
    t = np.concatenate(([0.0], np.cumsum(dt)))
    w = 2 * np.pi * np.array([0.3, 0.5, 0.7, 0.4, 0.6, 0.8, 0.35])
    q = np.sin(np.outer(t, w))
    dq = w * np.cos(np.outer(t, w))
    tau = q.copy()
    tk, qk, _dqk, ddqk, _ = prepare(t, q, dq, tau)
    truth = -w ** 2 * np.sin(np.outer(tk, w))
    np.testing.assert_allclose(qk, np.sin(np.outer(tk, w)), atol=2e-4)
    assert np.abs(ddqk - truth).max() < 0.01 * np.abs(truth).max()
    # uniform traffic is filtered as it is, on its own time stamps
    t_u = np.arange(6000) * 1e-3
    tu = prepare(t_u, np.sin(np.outer(t_u, w)), w * np.cos(np.outer(t_u, w)),
                 np.zeros((6000, 7)))[0]
    assert set(np.round(tu * 1e3).astype(int)) <= set(range(6000))


def test_never_worse_than_nominal_on_the_real_recording():
    """The real Panda (no hand: body 7 is panda_link7 alone), calibrated on its first 11 s:
    no joint fits worse than the nominal model, and on the last 10 s, held out, the residual
    stays below the nominal model's on every joint (measured 0.047-0.21 N·m RMS, the nominal
    model 0.21-0.65)."""
    from sim.arm import ArmParams as Arm

    t, q, dq, tau = real_recording()
    cut = int(np.searchsorted(t, 11.0))
    arm = calibrate_segments([(t[:cut], q[:cut], dq[:cut], tau[:cut])], end_effector="none",
                             source="real recording, first 11 s")
    before, after = np.array(arm.report["rms_before"]), np.array(arm.report["rms_after"])
    assert np.all(after <= before), (before, after)
    assert arm.report["fallback_joints"] == []
    _t, qh, dqh, ddqh, tauh = prepare(t[cut:], q[cut:], dq[cut:], tau[cut:])
    held = {}
    for name, a in (("nominal", Arm.nominal("none")), ("calibrated", arm)):
        model = ArmModel(arm=a)
        res = tauh - np.array([model.rnea(qh[k], dqh[k], ddqh[k]) for k in range(len(qh))])
        held[name] = np.sqrt(np.mean(res ** 2, axis=0))
    assert np.all(held["calibrated"] < held["nominal"]), held
    assert np.all(held["calibrated"] < 0.25), held


def test_the_posterior_is_as_sure_of_the_bodies_as_their_error_on_an_unseen_motion(bare, arm):
    """The calibration's posterior covariance (``ArmParams.posterior``) predicts how far the
    calibrated bodies' torques are from the true arm's on a motion it never saw: their error
    in units of its standard deviation has an RMS of about one per joint (measured 0.33-1.84;
    wide enough, not uselessly wide), and it round-trips through the arm file."""
    import pinocchio as pin

    truth = bare[0].arm
    P = arm.posterior
    assert P.shape == (133, 133) and np.allclose(P, P.T) and np.linalg.eigvalsh(P).min() > 0
    model = ArmModel().model
    data = model.createData()
    path = excitation_path(20.0, seed=4)
    d = arm.link_params.ravel() - truth.link_params.ravel()
    z = []
    for k in range(0, len(path), 50):
        W = pin.computeJointTorqueRegressor(model, data, path.q[k], path.dq[k], path.ddq[k])
        z.append(W @ d / np.sqrt(np.einsum("ij,jk,ik->i", W, P[:70, :70], W)))
    rms = np.sqrt(np.mean(np.square(z), axis=0))
    assert np.all(rms < 3.0) and np.all(rms > 0.2), rms


def test_the_arms_sensitivity_is_its_torques_derivative_along_the_posterior(arm):
    """``ArmDynamics.sensitivity``: the arm's torques moved along the posterior's factor ``F
    z`` (bodies and friction) change by ``sensitivity @ z`` (central differences on the
    arm model's own torques; exact in the bodies, to first order in the friction)."""
    from dataclasses import replace

    from sim.arm import ArmDynamics

    dyn = ArmDynamics(arm)
    rng = np.random.default_rng(2)
    q, dq, ddq = ArmModel().random_state(rng)
    z = rng.normal(size=dyn.considered) * 1e-3
    step = dyn._factor @ z

    def tau(sign):
        moved = replace(arm, link_params=arm.link_params + sign * step[:70].reshape(7, 10),
                        friction=arm.friction + sign * step[70:].reshape(7, 9),
                        posterior=None)
        return ArmModel(arm=moved).rnea(q, dq, ddq)

    want = (tau(1.0) - tau(-1.0)) / 2.0
    np.testing.assert_allclose(dyn.sensitivity(q, dq, ddq) @ z, want, rtol=1e-5,
                               atol=1e-9)


@pytest.fixture(scope="module")
def rotor_arm():
    """An arm whose drives add their rotors' inertia (armature) to its joint torques, as a
    torque from motor currents (or franky-sim's applied torque) does; its calibration motion
    with small white noise."""
    from dataclasses import replace

    truth = replace(ArmParams.nominal(), armature=np.array([0.2, 0.2, 0.2, 0.2, 0.07, 0.07,
                                                            0.07]))
    path = calibration_path(20.0)
    model = ArmModel(arm=truth)
    tau = np.array([model.rnea(q, dq, ddq) for q, dq, ddq in zip(path.q, path.dq, path.ddq,
                                                                  strict=True)])
    tau += np.random.default_rng(5).normal(0.0, 0.02, tau.shape)
    return truth, (path.t, path.q, path.dq, tau)


def test_the_armature_is_fitted_where_asked(rotor_arm):
    """``armature=True`` (``iem calibrate --armature``) recovers each joint's (joint 1's
    trades with body 1's inertia about its axis, which acts on that joint alone: the
    torque is what is checked there), and the arm's torques carry it (Pinocchio's
    armature); without it the armature's torque is left in the residual."""
    truth, traffic = rotor_arm
    arm = calibrate(*traffic, settings=Settings(armature=True))
    np.testing.assert_allclose(arm.armature[1:], truth.armature[1:], atol=0.01)
    without = calibrate(*traffic)
    assert not without.armature.any()
    assert max(arm.report["rms_after"]) < 0.03  # the noise, 0.02
    assert max(without.report["rms_after"]) > 2 * max(arm.report["rms_after"])
    _, q, dq, ddq, tau = prepare(*traffic)
    model = ArmModel(arm=arm)
    fitted = np.array([model.rnea(a, b, c) for a, b, c in zip(q, dq, ddq, strict=True)])
    assert np.sqrt(np.mean((tau - fitted) ** 2, axis=0)).max() < 0.03


def test_an_arm_without_armature_keeps_its_state_and_crc():
    """The arm file records an armature only when it has one: files made before keep their
    state, and the model files that name them by CRC stay valid."""
    from dataclasses import replace

    arm = ArmParams.nominal()
    assert "armature" not in arm.to_state()
    rotor = replace(arm, armature=np.full(7, 0.1))
    assert rotor.to_state()["armature"] == [0.1] * 7 and rotor.crc32 != arm.crc32
    back = ArmParams.from_state(rotor.to_state())
    np.testing.assert_array_equal(back.armature, rotor.armature)
    with pytest.raises(Exception, match="armature must be >= 0"):
        replace(arm, armature=np.full(7, -0.1))
