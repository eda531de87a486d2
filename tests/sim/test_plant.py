"""The MuJoCo plant: its torques against Pinocchio, its sensors, its payload and its gap."""

import mujoco
import numpy as np
import pytest

from iem.errors import PayloadError
from sim.family import default_test_payload, test_payloads
from sim.paths import new_task_path
from sim.payload import Payload
from sim.plant import ArmPlant, RealityGap, SensorModel, build_mujoco_model
from sim.robot import ArmModel


@pytest.fixture(scope="module")
def path():
    return new_task_path()


@pytest.fixture(scope="module")
def model():
    return ArmModel()


def test_tau_matches_rnea_with_payload_along_new_task_path(path, model):
    payload = default_test_payload()
    plant = ArmPlant(payload=payload, sensor=SensorModel.noiseless())
    plant.reset(path.q[0], path.dq[0])
    phi = payload.to_phi()
    worst = 0.0
    for k in range(len(path)):
        state = plant.step(path.q[k], path.dq[k], path.ddq[k])
        expected = model.rnea_with_payload(plant.last_q, plant.last_dq, plant.last_ddq, phi)
        worst = max(worst, float(np.abs(state.tau_J - expected).max()))
        np.testing.assert_array_equal(state.q, plant.last_q)
    assert worst < 1e-6


def test_mujoco_inverse_dynamics_matches_pinocchio_with_runtime_payload_change(model):
    mj = build_mujoco_model()
    data = mujoco.MjData(mj)
    plant = ArmPlant(payload=None, sensor=SensorModel.noiseless())
    rng = np.random.default_rng(1)
    for payload in [*test_payloads().values(), None]:
        plant.set_payload(payload)
        phi = np.zeros(10) if payload is None else payload.to_phi()
        for _ in range(10):
            q, dq, ddq = model.random_state(rng)
            data.qpos[:], data.qvel[:], data.qacc[:] = q, dq, ddq
            mujoco.mj_inverse(plant.model, data)
            expected = (model.rnea(q, dq, ddq) if payload is None
                        else model.rnea_with_payload(q, dq, ddq, phi))
            np.testing.assert_allclose(data.qfrc_inverse, expected, atol=1e-9)
    assert mj.nq == 7


def test_no_contacts_and_no_limits():
    plant = ArmPlant()
    flags = plant.model.opt.disableflags
    assert flags & mujoco.mjtDisableBit.mjDSBL_CONTACT
    assert flags & mujoco.mjtDisableBit.mjDSBL_LIMIT
    # a configuration that folds the arm onto itself produces no contact forces
    plant.reset([0, 1.7, 0, -3.0, 0, 3.7, 0])
    plant.step(plant.q, np.zeros(7), np.zeros(7))
    assert plant.data.ncon == 0
    assert np.all(np.abs(plant.last_tau) < 100)


def test_payload_change_between_steps_takes_effect(path):
    heavy = test_payloads()["test-4w"]
    plant = ArmPlant(payload=None, sensor=SensorModel.noiseless())
    plant.reset(path.q[0])
    before = plant.step(path.q[0], np.zeros(7), np.zeros(7)).tau_J
    plant.set_payload(heavy)
    plant.set_controller_load(heavy)
    after = plant.step(path.q[0], np.zeros(7), np.zeros(7)).tau_J
    # at rest the extra torque is gravity on the payload: Y(q, 0, 0) @ phi
    y = ArmModel().payload_regressor(plant.last_q, plant.last_dq, plant.last_ddq)
    assert np.abs(after - before).max() > 1.0
    np.testing.assert_allclose(after - before, y @ heavy.to_phi(), atol=1e-3)


def test_sensor_noise_is_seeded_and_has_the_documented_spread(path):
    def run(seed):
        plant = ArmPlant(payload=default_test_payload(), seed=seed)
        plant.reset(path.q[0])
        rows = []
        for k in range(2000):
            s = plant.step(path.q[k], path.dq[k], path.ddq[k])
            rows.append(np.concatenate((s.q - plant.last_q, s.dq - plant.last_dq,
                                        s.tau_J - plant.last_tau)))
        return np.array(rows)

    a, b, c = run(3), run(3), run(4)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    std = a.std(axis=0)
    np.testing.assert_allclose(std[:7], 1e-4, rtol=0.1)
    np.testing.assert_allclose(std[7:14], 2e-3, rtol=0.1)
    np.testing.assert_allclose(std[14:], 0.05, rtol=0.1)
    assert SensorModel() == SensorModel(1e-4, 2e-3, 0.05)


def test_reality_gap_changes_the_plant_not_the_nominal_model(path, model):
    gap = RealityGap(seed=1)
    plant = ArmPlant(sensor=SensorModel.noiseless(), gap=gap)
    plant.reset(path.q[0])
    s = plant.step(path.q[0], np.zeros(7), np.zeros(7))
    # at rest on target the command is the nominal model's gravity torque (read through
    # the sensor's gain, drift and offset)...
    gravity = model.rnea(path.q[0], np.zeros(7), np.zeros(7))
    np.testing.assert_allclose(s.tau_J - plant.arm.offset,
                               gap.unmodelled().sensor(0.0, gravity), atol=1e-9)
    assert np.abs(s.tau_J - plant.arm.offset - gravity).max() > 1e-3  # the gain error
    # ...which the gapped arm does not balance: it accelerates
    assert np.abs(plant.last_ddq).max() > 1e-3
    masses = [plant.model.body(f"panda_link{i}").mass[0] for i in range(1, 8)]
    ref = build_mujoco_model()
    nominal_masses = [ref.body(f"panda_link{i}").mass[0] for i in range(1, 8)]
    assert not np.allclose(masses, nominal_masses)
    np.testing.assert_allclose(masses, nominal_masses, rtol=0.051)


def test_controller_load_improves_tracking(path):
    payload = test_payloads()["test-4w"]
    errors = {}
    for label, load in (("none", None), ("true", payload)):
        plant = ArmPlant(payload=payload, sensor=SensorModel.noiseless(), controller_load=load)
        out = plant.follow(path)
        errors[label] = np.abs(out.q_ref - out.q_true)[500:].max()  # rad, worst joint
    # with the true load only the 1 ms Euler discretisation is left (about 1e-5 rad)
    assert errors["true"] < 1e-4
    assert errors["none"] > 100 * errors["true"]


def test_follow_records_consistent_rollout(path):
    plant = ArmPlant(payload=default_test_payload(), seed=0)
    out = plant.follow(path.slice(0.0, 0.5))  # both ends included
    assert len(out) == 501 and out.features.shape == (501, 21)
    np.testing.assert_allclose(np.diff(out.t), 1e-3)
    assert np.abs(out.q - out.q_true).max() < 1e-3


def test_follow_mounts_payloads_at_given_samples(path, model):
    """``mount={k: p}``: from sample k the torque is the new payload's, the controller's load
    unchanged."""
    p3, p4 = default_test_payload(), test_payloads()["test-4w"]
    short = path.slice(0.0, 0.2)
    plant = ArmPlant(payload=p3, sensor=SensorModel.noiseless(), controller_load=p3)
    out = plant.follow(short, mount={100: p4})
    assert plant.payload is p4 and plant.controller_load is p3
    for k, phi in ((99, p3.to_phi()), (100, p4.to_phi()), (200, p4.to_phi())):
        tau = model.rnea_with_payload(out.q_true[k], out.dq_true[k], out.ddq_true[k], phi)
        np.testing.assert_allclose(out.tau_true[k], tau, atol=1e-6)


def test_inconsistent_payload_is_rejected():
    plant = ArmPlant()
    with pytest.raises(PayloadError, match="positive definite"):
        plant.set_payload(Payload("bad", 1.0, (0, 0, 0), (-1, 0, 0, 1, 0, 1)))
