"""The realistic plant: one reality gap (links, friction, offsets), checked against Pinocchio."""

import numpy as np
import pinocchio as pin
import pytest

from iem.sensor import DEFAULT_SENSOR
from iem.sensor import SensorModel as CoreSensorModel
from sim.arm import GAZ_PHI, ArmParams, gaz_friction, gaz_friction_jacobian
from sim.family import default_test_payload
from sim.paths import excitation_path
from sim.plant import PandaPlant, RealityGap, SensorModel, build_mujoco_model
from sim.robot import PandaModel, nominal_link_params, panda_urdf


@pytest.fixture(scope="module")
def rollout():
    payload = default_test_payload()
    plant = PandaPlant(payload=payload, sensor=SensorModel.noiseless(), gap=RealityGap(seed=3),
                       controller_load=payload)
    return plant, payload, plant.follow(excitation_path(2.0))


def _independent_rnea(arm: ArmParams, payload_phi_pin, q, dq, ddq):
    """Pinocchio RNEA of the URDF with the arm's bodies written in, built here from scratch
    (not through sim.robot), plus Gaz's friction written out and the offsets."""
    full = pin.buildModelFromUrdf(str(panda_urdf()))
    locked = [full.getJointId(n) for n in ("panda_finger_joint1", "panda_finger_joint2")]
    model = pin.buildReducedModel(full, locked, pin.neutral(full))
    for j in range(1, 8):
        model.inertias[j] = pin.Inertia.FromDynamicParameters(arm.link_params[j - 1])
    flange = model.frames[model.getFrameId("panda_link8")]
    model.inertias[7] += flange.placement.act(pin.Inertia.FromDynamicParameters(payload_phi_pin))
    data = model.createData()
    p1, p2, p3 = arm.friction.T
    fric = p1 / (1 + np.exp(-p2 * (dq + p3))) - p1 / (1 + np.exp(-p2 * p3))
    return pin.rnea(model, data, q, dq, ddq) + fric + arm.offset


def test_plant_torque_is_rnea_of_the_perturbed_arm_plus_friction_plus_offset(rollout):
    plant, payload, r = rollout
    arm = plant.arm
    phi_pin = pin.Inertia.FromDynamicParameters(
        np.asarray(payload.to_phi())[[0, 1, 2, 3, 4, 5, 7, 6, 8, 9]]).toDynamicParameters()
    nominal = PandaModel()
    worst = worst_nominal = 0.0
    for k in range(0, len(r), 25):
        truth = _independent_rnea(arm, phi_pin, r.q_true[k], r.dq_true[k], r.ddq_true[k])
        worst = max(worst, float(np.abs(truth - r.tau[k]).max()))
        worst_nominal = max(worst_nominal, float(np.abs(
            nominal.rnea_with_payload(r.q_true[k], r.dq_true[k], r.ddq_true[k],
                                      payload.to_phi()) - r.tau[k]).max()))
    assert worst < 1e-9
    assert worst_nominal > 0.2  # the gap is there: the nominal model misses it


def test_gap_is_seeded_and_within_its_bounds():
    model = build_mujoco_model()
    a, b, c = (RealityGap(seed=s).realise(model) for s in (4, 4, 5))
    np.testing.assert_array_equal(a.link_params, b.link_params)
    np.testing.assert_array_equal(a.offset, b.offset)
    assert not np.allclose(a.link_params, c.link_params)
    nominal = nominal_link_params()
    rel = a.link_params[:, 0] / nominal[:, 0] - 1.0
    # link 7's body holds the hand too, so its relative change is smaller than the link's
    assert np.all(np.abs(rel) <= 0.05 + 1e-12) and np.abs(rel).max() > 0.005
    factors = a.friction / GAZ_PHI
    assert np.all((factors >= 0.7) & (factors <= 1.3))
    offsets = np.concatenate([RealityGap(seed=s).joints()[1] for s in range(40)])
    assert 0.07 < offsets.std() < 0.13
    plain = RealityGap(friction_factor=None, offset_std=0.0).realise(model)
    assert not plain.friction.any() and not plain.offset.any()


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


def test_sensor_model_lives_in_iem():
    assert SensorModel is CoreSensorModel
    assert SensorModel(1e-4, 2e-3, 0.05) == DEFAULT_SENSOR
    from iem.ensemble import SENSOR_NOISE

    np.testing.assert_array_equal(SENSOR_NOISE, DEFAULT_SENSOR.sigmas)


def test_controller_on_the_real_arm_model_tracks_better():
    path = excitation_path(3.0)
    gap = RealityGap(seed=3)
    nominal = PandaPlant(sensor=SensorModel.noiseless(), gap=gap).follow(path)
    plant = PandaPlant(sensor=SensorModel.noiseless(), gap=gap)
    own = PandaPlant(sensor=SensorModel.noiseless(), gap=gap,
                     controller_arm=plant.arm).follow(path)
    assert own.tracking_error().max() < 0.1 * nominal.tracking_error().max()
