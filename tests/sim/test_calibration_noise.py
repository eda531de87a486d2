"""The calibrated arm's floors the calibration cannot see on its own motion."""

import numpy as np

from iem.physics.torque_noise import TorqueNoise
from sim.arm import ArmParams
from sim.calibration_noise import pose_floor

NOISE = TorqueNoise(std=(0.05,) * 7, weight=(1.0,) * 7, offset_std=(0.01,) * 7)
Q_LOW = np.array([-1.0, -0.8, -1.0, -2.6, -0.8, 1.4, -0.4])
Q_HIGH = np.array([1.2, 0.4, 0.7, -1.4, 1.3, 3.0, 1.9])


def _arm_with_body7_mass(extra: float) -> ArmParams:
    arm = ArmParams.nominal()
    params = arm.link_params.copy()
    params[6, 0] += extra  # a point mass at joint 7's origin: payload mass to the regression
    return ArmParams(params, arm.friction, arm.offset)


def test_pose_floor_is_the_jackknife_spread_of_what_the_folds_read_as_payload():
    extras = np.array([0.00, 0.02, -0.01, 0.03, 0.01])
    arms = [_arm_with_body7_mass(e) for e in extras]
    floor = pose_floor(arms, Q_LOW, Q_HIGH, NOISE, lines=3)
    k = len(extras)
    expected = np.sqrt((k - 1) / k * np.sum(np.square(extras - extras.mean())))
    assert abs(floor[0] - expected) < 0.05 * expected
    assert np.all(floor[4:] < 0.01 * expected)  # quasi-static lines do not see inertia


def test_pose_floor_of_arms_that_agree_is_zero():
    arms = [_arm_with_body7_mass(0.01)] * 4
    assert np.allclose(pose_floor(arms, Q_LOW, Q_HIGH, NOISE, lines=2), 0.0, atol=1e-9)
    assert np.all(pose_floor(arms[:1], Q_LOW, Q_HIGH, NOISE) == 0.0)

