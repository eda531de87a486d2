"""The realistic plant: one reality gap (links, friction, offsets, and what no arm model
describes), checked against Pinocchio and the friction model written out here."""

import copy
import pickle

import numpy as np
import pinocchio as pin
import pytest

from iem.sensor import DEFAULT_SENSOR
from iem.sensor import SensorModel as CoreSensorModel
from sim.arm import ArmParams, load_arm, save_arm
from sim.description import builtin_file
from sim.family import default_test_payload
from sim.friction import (
    FRICTION_COLUMNS,
    GAZ_PHI,
    FrictionPoints,
    friction_jacobian,
    friction_torque,
    full_friction,
    gaz_friction,
    gaz_friction_jacobian,
)
from sim.paths import excitation_path
from sim.plant import ArmPlant, RealityGap, SensorModel, build_mujoco_model
from sim.robot import ArmModel, arm_model, nominal_link_params


@pytest.fixture(scope="module")
def rollout():
    payload = default_test_payload()
    plant = ArmPlant(payload=payload, sensor=SensorModel.noiseless(),
                       gap=RealityGap(seed=3).modelled_only(), controller_load=payload)
    return plant, payload, plant.follow(excitation_path(2.0))


def _sigmoid(x):
    return 1.0 / (1.0 + np.exp(-x))


def _friction(friction, dq):
    """The friction model written out (Coulomb as Gaz's sigmoid, viscous and Stribeck per
    direction), not through sim.arm."""
    p1, p2, p3 = friction[:, 0], friction[:, 1], friction[:, 2]
    out = p1 / (1 + np.exp(-p2 * (dq + p3))) - p1 / (1 + np.exp(-p2 * p3))
    if friction.shape[1] == 3:
        return out
    fvp, fvn, fsp, fsn, vsp, vsn = friction[:, 3:].T
    w = _sigmoid(p2 * dq)
    viscous = fvp * dq * w + fvn * dq * (1 - w)
    stribeck = ((2 * w - 1) * w * fsp * np.exp(-(dq / vsp) ** 2)
                + (2 * w - 1) * (1 - w) * fsn * np.exp(-(dq / vsn) ** 2))
    return out + viscous + stribeck


def _link_model(arm: ArmParams, payload_phi_pin=None):
    """Pinocchio model of the URDF with the arm's bodies written in, built here from scratch
    (not through sim.robot)."""
    full = pin.buildModelFromUrdf(str(builtin_file("panda")))
    locked = [full.getJointId(n) for n in ("panda_finger_joint1", "panda_finger_joint2")]
    model = pin.buildReducedModel(full, locked, pin.neutral(full))
    for j in range(1, 8):
        model.inertias[j] = pin.Inertia.FromDynamicParameters(arm.link_params[j - 1])
    if payload_phi_pin is not None:
        flange = model.frames[model.getFrameId("panda_link8")]
        model.inertias[7] += flange.placement.act(
            pin.Inertia.FromDynamicParameters(payload_phi_pin))
    return model, model.createData()


def test_plant_torque_is_rnea_of_the_perturbed_arm_plus_friction_plus_offset(rollout):
    plant, payload, r = rollout
    arm = plant.arm
    assert arm.friction.shape == (7, 9)  # viscous and Stribeck friction, per direction
    phi_pin = pin.Inertia.FromDynamicParameters(
        np.asarray(payload.to_phi())[[0, 1, 2, 3, 4, 5, 7, 6, 8, 9]]).toDynamicParameters()
    model, data = _link_model(arm, phi_pin)
    nominal = ArmModel()
    worst = worst_nominal = 0.0
    for k in range(0, len(r), 25):
        q, dq, ddq = r.q_true[k], r.dq_true[k], r.ddq_true[k]
        truth = pin.rnea(model, data, q, dq, ddq) + _friction(arm.friction, dq) + arm.offset
        worst = max(worst, float(np.abs(truth - r.tau[k]).max()))
        worst_nominal = max(worst_nominal, float(np.abs(
            nominal.rnea_with_payload(q, dq, ddq, payload.to_phi()) - r.tau[k]).max()))
    assert worst < 1e-9
    assert worst_nominal > 0.2  # the gap is there: the nominal model misses it


def test_the_unmodelled_effects_act_as_documented():
    """With them (the default gap), the sensor reads ``(1 + gain) tau + drift + offset`` of
    the applied ``tau``, and the links move under ``tau`` less the friction scaled by load
    and warm-up and less the ripples: checked step by step against Pinocchio's RNEA of the
    perturbed links and the effects written out, on a plant that has already run (its
    slow effects' clock survives the reset)."""
    gap = RealityGap(seed=3)
    plant = ArmPlant(sensor=SensorModel.noiseless(), gap=gap)
    first = plant.follow(excitation_path(0.5))
    r = plant.follow(excitation_path(1.0, seed=2))
    arm, u = plant.arm, gap.unmodelled()
    model, data = _link_model(arm)
    worst = gap_seen = 0.0
    for k in range(0, len(r), 20):
        age = len(first) * 1e-3 + r.t[k]  # the first run's 501 steps of 1 ms, then this one
        q, dq, ddq = r.q_true[k], r.dq_true[k], r.ddq_true[k]
        drift = u.drift * np.sin(2 * np.pi * age / u.drift_period + u.drift_phase)
        applied = (r.tau_true[k] - arm.offset - drift) / (1 + u.gain)
        scale = (1 + u.load * np.abs(applied) / arm_model().tau_max) * (
            1 - u.warmup * (1 - np.exp(-age / 600.0)))
        ripple = (u.ripple * np.sin(u.wavenumber * q[:, None] + u.ripple_phase)).sum(1)
        links = pin.rnea(model, data, q, dq, ddq)
        worst = max(worst, float(np.abs(
            applied - links - _friction(arm.friction, dq) * scale - ripple).max()))
        gap_seen = max(gap_seen, float(np.abs(
            r.tau_true[k] - ArmModel(arm=arm).rnea(q, dq, ddq)).max()))
    assert worst < 1e-8
    assert gap_seen > 0.05  # what the arm model misses


def test_gap_is_seeded_and_within_its_bounds():
    model = build_mujoco_model()
    a, b, c = (RealityGap(seed=s).realise(model) for s in (4, 4, 5))
    np.testing.assert_array_equal(a.link_params, b.link_params)
    np.testing.assert_array_equal(a.friction, b.friction)
    np.testing.assert_array_equal(a.offset, b.offset)
    assert not np.allclose(a.link_params, c.link_params)
    assert not np.allclose(a.friction, c.friction)
    nominal = nominal_link_params()
    rel = a.link_params[:, 0] / nominal[:, 0] - 1.0
    # link 7's body holds the hand too, so its relative change is smaller than the link's
    assert np.all(np.abs(rel) <= 0.05 + 1e-12) and np.abs(rel).max() > 0.005
    gap = RealityGap()
    factors = a.friction[:, :3] / GAZ_PHI
    assert np.all((factors >= 0.7) & (factors <= 1.3))
    assert np.all((a.friction[:, 3:5] >= 0) & (a.friction[:, 3:5] <= gap.viscous))
    assert np.all(a.friction[:, 5:7] >= 0)
    assert np.all(a.friction[:, 5:7] <= gap.stribeck * a.friction[:, :1])
    assert np.all((a.friction[:, 7:9] >= 0.05) & (a.friction[:, 7:9] <= 0.3))
    assert np.all(a.friction[:, 3:5] != a.friction[:, 4:2:-1])  # either direction its own
    offsets = np.concatenate([RealityGap(seed=s).joints()[1] for s in range(40)])
    assert 0.07 < offsets.std() < 0.13
    plain = RealityGap(friction_factor=None, offset_std=0.0).realise(model)
    assert not plain.friction.any() and not plain.offset.any()
    # the links, Gaz's factors and the offsets of a seed stay what they were without the
    # other effects (each group of draws has its own stream)
    gaz = RealityGap(seed=4, viscous=0.0, stribeck=0.0).modelled_only().realise(model)
    assert gaz.friction.shape == (7, 3)
    np.testing.assert_array_equal(gaz.friction, a.friction[:, :3])
    np.testing.assert_array_equal(gaz.link_params, a.link_params)
    np.testing.assert_array_equal(gaz.offset, a.offset)


def test_the_unmodelled_effects_are_seeded_and_within_their_bounds():
    gap = RealityGap(seed=4)
    u, again, other = gap.unmodelled(), RealityGap(seed=4).unmodelled(), RealityGap(
        seed=5).unmodelled()
    for name in u.__dataclass_fields__:
        np.testing.assert_array_equal(getattr(u, name), getattr(again, name))
        if name != "tau_max":  # the arm model's limits, not drawn
            assert not np.allclose(getattr(u, name), getattr(other, name)), name
    assert np.all((u.load >= 0) & (u.load <= gap.load_friction))
    assert np.all((u.warmup >= 0) & (u.warmup <= gap.warmup))
    assert np.all(np.abs(u.gain) <= gap.gain_rel) and np.abs(u.gain).max() > 0.005
    assert np.all((u.drift >= 0) & (u.drift <= gap.offset_drift))
    big = np.array([gap.ripple_large] * 4 + [gap.ripple_small] * 3)
    assert np.all((u.ripple >= 0.5 * big) & (u.ripple <= big))
    assert np.all((u.wavenumber[:, 0] >= 0.5) & (u.wavenumber[:, 0] <= 3.0))
    assert np.all((u.wavenumber[:, 1] >= 25.0) & (u.wavenumber[:, 1] <= 60.0))
    assert not RealityGap(seed=4).modelled_only().unmodelled().any and u.any
    # the same seed gives the same torques, another seed others
    path = excitation_path(0.3)

    def torques(seed):
        return ArmPlant(gap=RealityGap(seed=seed), seed=1).follow(path).tau

    a, b, c = torques(4), torques(4), torques(5)
    np.testing.assert_array_equal(a, b)
    assert np.abs(a - c).max() > 0.05


def test_gaz_friction_shape_and_jacobian():
    dq = np.linspace(-1.0, 1.0, 7)
    np.testing.assert_array_equal(gaz_friction(np.zeros(7), GAZ_PHI), np.zeros(7))
    far = gaz_friction(np.full(7, 5.0), GAZ_PHI) - gaz_friction(np.full(7, -5.0), GAZ_PHI)
    np.testing.assert_allclose(far, GAZ_PHI[:, 0], rtol=1e-6)  # phi1: the full swing
    jac = gaz_friction_jacobian(dq[None], GAZ_PHI)[0]
    for c in range(3):
        h = np.zeros((7, 3))
        h[:, c] = 1e-6
        fd = (gaz_friction(dq, GAZ_PHI + h) - gaz_friction(dq, GAZ_PHI - h)) / 2e-6
        np.testing.assert_allclose(jac[:, c], fd, rtol=1e-5, atol=1e-9)


def _a_full_friction(seed=0):
    rng = np.random.default_rng(seed)
    f = full_friction(GAZ_PHI * rng.uniform(0.7, 1.3, (7, 3)))
    f[:, 3:5] = rng.uniform(0.0, 0.5, (7, 2))
    f[:, 5:7] = rng.uniform(-0.3, 0.5, (7, 2))
    f[:, 7:9] = rng.uniform(0.03, 0.4, (7, 2))
    return f


def test_friction_model_and_its_jacobian_against_finite_differences():
    f = _a_full_friction()
    dq = np.random.default_rng(1).uniform(-2.0, 2.0, (200, 7))
    dq[:5] = np.array([0.0, 1e-4, -1e-4, 0.02, -0.02])[:, None]  # through zero
    np.testing.assert_allclose(friction_torque(dq, f), _friction(f, dq), rtol=1e-12,
                               atol=1e-14)
    np.testing.assert_array_equal(friction_torque(np.zeros(7), f), np.zeros(7))
    jac = friction_jacobian(dq, f)
    assert jac.shape == (200, 7, len(FRICTION_COLUMNS))
    for c in range(len(FRICTION_COLUMNS)):
        h = np.zeros_like(f)
        h[:, c] = 1e-6 * max(1.0, np.abs(f[:, c]).max())
        fd = (friction_torque(dq, f + h) - friction_torque(dq, f - h)) / (2 * h[0, c])
        np.testing.assert_allclose(jac[..., c], fd, rtol=1e-6, atol=1e-8,
                                   err_msg=FRICTION_COLUMNS[c])
    # direction-dependent: once through zero (the sigmoid's width, 1/phi2, sets where) the
    # viscous coefficient of one direction acts on that direction alone
    fast = np.full((1, 7), 1.5)
    side = friction_jacobian(np.vstack((fast, -fast)), f)
    np.testing.assert_allclose(side[0, :, 3], 1.5, rtol=0.01)
    np.testing.assert_allclose(side[1, :, 4], -1.5, rtol=0.01)
    assert np.abs(side[0, :, 4]).max() < 0.015 and np.abs(side[1, :, 3]).max() < 0.015


def test_friction_at_one_velocity_is_the_batch_models_whatever_was_asked_before():
    """FrictionPoints (the estimator's path: one velocity at a time, terms kept) gives
    friction_torque's numbers exactly and friction_jacobian's to rounding (its sums are
    grouped otherwise: a last bit apart), for a full and a Gaz array,
    asked fresh, again, in another order and after its kept terms were dropped; the torque it
    keeps cannot be written, and an arm's copies share one instance."""
    rng = np.random.default_rng(5)
    dq = rng.uniform(-2.0, 2.0, (40, 7))
    dq[:3] = np.array([0.0, 1e-4, -0.02])[:, None]
    for f in (_a_full_friction(), GAZ_PHI):
        points = FrictionPoints(f)
        torque, jac = friction_torque(dq, f), friction_jacobian(dq, f)
        order = np.concatenate((np.arange(40), rng.permutation(40), np.arange(40)[::-1]))
        for i in order:  # more velocities than it keeps: entries are dropped and made again
            got = points.torque(dq[i])
            np.testing.assert_array_equal(got, torque[i])
            assert not got.flags.writeable
            if f.shape[1] == len(FRICTION_COLUMNS):
                np.testing.assert_allclose(points.jacobian(dq[i]), jac[i], rtol=1e-14,
                                           atol=1e-16)
        with pytest.raises(ValueError, match=r"one velocity \(7,\)"):
            points.torque(dq[:2])
    with pytest.raises(ValueError, match="full"):
        FrictionPoints(GAZ_PHI).jacobian(dq[0])
    arm = ArmParams(nominal_link_params(), _a_full_friction(), np.full(7, 0.02))
    twin = ArmParams.from_state(arm.to_state())
    assert twin.friction_points is arm.friction_points
    for copied in (copy.deepcopy(arm), pickle.loads(pickle.dumps(arm))):
        assert "_friction_points" not in vars(copied)  # the kept terms are not carried
        assert copied.friction_points is arm.friction_points and copied.crc32 == arm.crc32
    np.testing.assert_array_equal(arm.joint_torque(dq[7]), friction_torque(dq, arm.friction)[7]
                                  + 0.02)


def test_a_gaz_array_is_gaz_to_the_bit_and_old_arm_files_load(tmp_path):
    """A ``(7, 3)`` friction array (Gaz's model, as every arm file written before the full
    model) gives Gaz's torques exactly, as does the same array made full; an arm file with
    one keeps its state, hence the CRC that model files record."""
    dq = np.random.default_rng(2).uniform(-2.0, 2.0, (300, 7))
    ref = gaz_friction(dq, GAZ_PHI)
    np.testing.assert_array_equal(friction_torque(dq, GAZ_PHI), ref)
    np.testing.assert_array_equal(friction_torque(dq, full_friction(GAZ_PHI)), ref)
    np.testing.assert_array_equal(friction_jacobian(dq, GAZ_PHI),
                                  gaz_friction_jacobian(dq, GAZ_PHI))
    arm = ArmParams(nominal_link_params(), GAZ_PHI, np.full(7, 0.01))
    np.testing.assert_array_equal(arm.joint_torque(dq), ref + 0.01)
    save_arm(arm, tmp_path / "arm.msgpack")
    back = load_arm(tmp_path / "arm.msgpack")
    assert back.friction.shape == (7, 3) and back.crc32 == arm.crc32
    assert back.to_state()["friction"] == GAZ_PHI.tolist()
    np.testing.assert_array_equal(back.joint_torque(dq), ref + 0.01)
    full = ArmParams(nominal_link_params(), _a_full_friction(), np.zeros(7))
    back = ArmParams.from_state(full.to_state())
    np.testing.assert_array_equal(back.friction, full.friction)


def test_a_bad_friction_array_says_what_is_valid():
    from iem.errors import InvalidInputError

    with pytest.raises(InvalidInputError, match=r"\(7, 3\).*\(7, 9\)"):
        ArmParams(nominal_link_params(), np.zeros((7, 4)), np.zeros(7))
    bad = _a_full_friction()
    bad[2, 7] = 0.0
    with pytest.raises(InvalidInputError, match="Stribeck velocities"):
        ArmParams(nominal_link_params(), bad, np.zeros(7))


def test_sensor_model_lives_in_iem():
    assert SensorModel is CoreSensorModel
    assert SensorModel(1e-4, 2e-3, 0.05) == DEFAULT_SENSOR
    from iem.ensemble.learner import SENSOR_NOISE

    np.testing.assert_array_equal(SENSOR_NOISE, DEFAULT_SENSOR.sigmas)


def test_controller_on_the_real_arm_model_tracks_better():
    path = excitation_path(3.0)
    gap = RealityGap(seed=3).modelled_only()
    nominal = ArmPlant(sensor=SensorModel.noiseless(), gap=gap).follow(path)
    plant = ArmPlant(sensor=SensorModel.noiseless(), gap=gap)
    own = ArmPlant(sensor=SensorModel.noiseless(), gap=gap,
                     controller_arm=plant.arm).follow(path)
    assert (np.abs(own.q_ref - own.q_true).max()
            < 0.1 * np.abs(nominal.q_ref - nominal.q_true).max())
