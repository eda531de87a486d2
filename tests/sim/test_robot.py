"""The Pinocchio Panda: payload regressor against RNEA, kinematics against MuJoCo."""

import mujoco
import numpy as np
import pinocchio as pin
import pytest

from sim.plant import build_mujoco_model
from sim.robot import PAPER_TO_PIN, ArmModel, phi_to_pin


def phi_from_pin(params: np.ndarray) -> np.ndarray:
    """Pinocchio dynamic-parameter order -> paper order (``(..., 10)`` arrays): the inverse
    permutation of :data:`sim.robot.PAPER_TO_PIN`, computed, not assumed to be itself."""
    return np.asarray(params)[..., np.argsort(PAPER_TO_PIN)]


@pytest.fixture(scope="module")
def model():
    return ArmModel()


def random_phi(rng):
    """A physically consistent payload phi (paper order) built independently of sim.payload."""
    m = rng.uniform(0.2, 3.0)
    c = rng.uniform(-0.1, 0.1, 3)
    a = rng.normal(size=(3, 3))
    rot, _ = np.linalg.qr(a)
    moments = rng.uniform(1e-3, 1e-2, 3)
    ic = rot @ np.diag(moments) @ rot.T
    io = ic + m * (c @ c * np.eye(3) - np.outer(c, c))
    return np.array([m, *(m * c), io[0, 0], io[0, 1], io[0, 2], io[1, 1], io[1, 2], io[2, 2]])


def test_seven_dof_with_flange(model):
    assert model.model.nq == 7 and model.model.nv == 7
    flange = model.model.frames[model.flange_id]
    assert flange.name == "panda_link8"
    np.testing.assert_allclose(flange.placement.translation, [0, 0, 0.107])


def test_regressor_equals_rnea_difference_at_100_states(model):
    rng = np.random.default_rng(42)
    worst = 0.0
    for _ in range(100):
        q, dq, ddq = model.random_state(rng)
        phi = random_phi(rng)
        diff = model.rnea_with_payload(q, dq, ddq, phi) - model.rnea(q, dq, ddq)
        worst = max(worst, np.abs(model.payload_regressor(q, dq, ddq) @ phi - diff).max())
    assert worst < 1e-9


def test_regressor_against_pinocchio_body_appended_independently(model):
    """Independent route: append the payload as a new body with Pinocchio and run RNEA."""
    rng = np.random.default_rng(7)
    phi = random_phi(rng)
    inertia = pin.Inertia.FromDynamicParameters(phi_to_pin(phi))
    with_payload = model.model.copy()
    with_payload.appendBodyToJoint(model.last_joint, inertia, model.flange_placement)
    data = with_payload.createData()
    for _ in range(20):
        q, dq, ddq = model.random_state(rng)
        expected = pin.rnea(with_payload, data, q, dq, ddq) - model.rnea(q, dq, ddq)
        np.testing.assert_allclose(model.payload_regressor(q, dq, ddq) @ phi, expected,
                                   atol=1e-9)


def test_rnea_and_regressor_agree_with_separate_calls(model):
    rng = np.random.default_rng(3)
    q, dq, ddq = model.random_state(rng)
    tau, y = model.rnea_and_regressor(q, dq, ddq)
    np.testing.assert_array_equal(tau, model.rnea(q, dq, ddq))
    np.testing.assert_array_equal(y, model.payload_regressor(q, dq, ddq))


def test_parameter_order_permutation_is_an_involution():
    v = np.arange(10.0)
    np.testing.assert_array_equal(phi_to_pin(phi_to_pin(v)), v)
    np.testing.assert_array_equal(phi_from_pin(phi_to_pin(v)), v)
    # paper Ixz (6) is Pinocchio's index 7, paper Iyy (7) is Pinocchio's index 6
    assert PAPER_TO_PIN[6] == 7 and PAPER_TO_PIN[7] == 6


def test_flange_position_matches_mujoco(model):
    mj = build_mujoco_model()
    data = mujoco.MjData(mj)
    rng = np.random.default_rng(5)
    body = mj.body("panda_link8").id
    for _ in range(20):
        q, _, _ = model.random_state(rng)
        data.qpos[:] = q
        mujoco.mj_kinematics(mj, data)
        np.testing.assert_allclose(model.flange_position(q), data.xpos[body], atol=1e-12)
    qs = np.array([model.random_state(rng)[0] for _ in range(5)])
    np.testing.assert_allclose(model.flange_positions(qs),
                               [model.flange_position(q) for q in qs], atol=1e-15)


def test_random_states_respect_limits(model):
    rng = np.random.default_rng(0)
    for _ in range(50):
        q, dq, ddq = model.random_state(rng)
        assert np.all(q >= model.q_min) and np.all(q <= model.q_max)
        assert np.all(np.abs(dq) <= model.dq_max) and np.all(np.abs(ddq) <= model.ddq_max)


def test_spatial_inertia_is_pinocchios_and_linear():
    from sim.robot import spatial_inertia

    rng = np.random.default_rng(4)
    for _ in range(10):
        inertia = pin.Inertia.Random()
        phi = phi_from_pin(inertia.toDynamicParameters())
        np.testing.assert_allclose(spatial_inertia(phi), inertia.matrix(), atol=1e-12)
    a, b = rng.normal(size=10), rng.normal(size=10)
    a[0] = 0.0  # no mass: pin.Inertia could not place the CoM, the linear form can
    np.testing.assert_allclose(spatial_inertia(2 * a - b),
                               2 * spatial_inertia(a) - spatial_inertia(b), atol=1e-12)


def test_mass_matrix_is_the_whole_symmetric_crba(model):
    """The mass matrix beside the regressor is CRBA's upper triangle mirrored: symmetric, the
    upper triangle Pinocchio's, and ``M ddq`` the torques RNEA adds for an acceleration."""
    rng = np.random.default_rng(5)
    for _ in range(20):
        q, dq, ddq = model.random_state(rng)
        _, _, mass = model.rnea_regressor_mass(q, dq, ddq)
        assert mass.shape == (7, 7) and np.array_equal(mass, mass.T)
        upper = pin.crba(model.model, model.data, q)
        assert np.array_equal(np.triu(mass), np.triu(upper))
        zero = np.zeros(7)
        inertial = model.rnea(q, zero, ddq) - model.rnea(q, zero, zero)
        np.testing.assert_allclose(mass @ ddq, inertial, rtol=1e-9, atol=1e-9)
