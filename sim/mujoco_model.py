"""The plant's MuJoCo model: example-robot-data's ``panda_collision.urdf``, fingers welded,
joint damping, armature and friction zeroed, contacts and joint limits off, and the payload
as a body of its own on the flange, changeable between two steps."""

from __future__ import annotations

import mujoco
import numpy as np

from iem.types import NOMINAL_RATE_HZ

from .payload import Payload
from .robot import panda_urdf

DT = 1.0 / NOMINAL_RATE_HZ
"""Control and integration period, s (1 kHz, as the Franka's real-time loop)."""

PAYLOAD_BODY = "payload"
LINK_BODIES = tuple(f"panda_link{i}" for i in range(1, 8))


def payload_principal(payload: Payload) -> tuple[np.ndarray, np.ndarray]:
    """Principal moments and the MuJoCo quaternion of the principal axes (in the flange)."""
    moments, axes = np.linalg.eigh(payload.inertia_matrix)
    if np.linalg.det(axes) < 0:
        axes[:, 0] *= -1.0
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, axes.flatten())
    return moments, quat


def build_mujoco_model() -> mujoco.MjModel:
    """Compile the plant's MuJoCo model (a fresh copy each call)."""
    spec = mujoco.MjSpec.from_file(str(panda_urdf(collision=True)))
    spec.compiler.fusestatic = False  # keep the payload its own body, changeable at run time
    for eq in list(spec.equalities):  # the URDF's finger mimic constraint
        spec.delete(eq)
    for joint in list(spec.joints):
        if "finger" in joint.name:
            spec.delete(joint)  # fingers welded to the hand, as Pinocchio's locked joints
        else:
            joint.damping = np.zeros(3)
            joint.armature = 0.0
            joint.frictionloss = 0.0
    spec.option.timestep = DT
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_EULER
    spec.option.disableflags |= (mujoco.mjtDisableBit.mjDSBL_CONTACT
                                 | mujoco.mjtDisableBit.mjDSBL_LIMIT)
    spec.body("panda_link8").add_body(name=PAYLOAD_BODY, pos=[0.0, 0.0, 0.0], mass=0.0,
                                      ipos=[0.0, 0.0, 0.0], inertia=[0.0, 0.0, 0.0])
    return spec.compile()
