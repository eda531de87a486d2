"""The plant's MuJoCo model: the arm's description (:mod:`sim.description`, the same text
Pinocchio reads, with what hangs beyond the flange: the Panda's hand, its fingers welded),
joint damping, armature and friction zeroed, contacts and joint limits off, and the payload
as a body of its own on the flange, changeable between two steps."""

from __future__ import annotations

import mujoco
import numpy as np

from iem.types import NOMINAL_RATE_HZ

from .description import ArmDescription, described
from .payload import Payload

DT = 1.0 / NOMINAL_RATE_HZ
"""Control and integration period, s (1 kHz, as the Franka's real-time loop)."""

PAYLOAD_BODY = "payload"
END_EFFECTOR_BODY = "end_effector"


def _principal(mass: float, inertia_com: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Principal moments and the MuJoCo quaternion of the principal axes of a body's inertia
    about its CoM."""
    moments, axes = np.linalg.eigh(np.asarray(inertia_com, dtype=float))
    if np.linalg.det(axes) < 0:
        axes[:, 0] *= -1.0
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, axes.flatten())
    return moments, quat


def payload_principal(payload: Payload) -> tuple[np.ndarray, np.ndarray]:
    """Principal moments and the MuJoCo quaternion of the principal axes (in the flange)."""
    return _principal(payload.mass, payload.inertia_matrix)


def build_mujoco_model(description=None, end_effector=None) -> mujoco.MjModel:
    """Compile the plant's MuJoCo model of the arm ``description`` (None: the default arm
    model) carrying ``end_effector`` on its flange (a spec, :mod:`sim.end_effector`; None:
    the description's default); a fresh copy each call. Its arm bodies are
    ``description.link_bodies``; the end effector is the file's own (the Panda's hand, its
    fingers welded) or a body ``end_effector`` on the flange."""
    from .end_effector import end_effector_of
    desc: ArmDescription = described(description)
    own = desc.carries_own(end_effector)
    spec = mujoco.MjSpec.from_string(desc.full_text if own else desc.text)
    spec.compiler.fusestatic = False  # keep the payload its own body, changeable at run time
    for eq in list(spec.equalities):  # e.g. a gripper's mimic constraint
        spec.delete(eq)
    for joint in list(spec.joints):
        if joint.name not in desc.joint_names:
            spec.delete(joint)  # welded, as Pinocchio's locked joints
        else:
            joint.damping = np.zeros(3)
            joint.armature = 0.0
            joint.frictionloss = 0.0
    spec.option.timestep = DT
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_EULER
    spec.option.disableflags |= (mujoco.mjtDisableBit.mjDSBL_CONTACT
                                 | mujoco.mjtDisableBit.mjDSBL_LIMIT)
    flange = spec.body(desc.flange)
    ee = end_effector_of(end_effector, desc)
    if not own and ee.mass > 0.0:
        moments, quat = _principal(ee.inertia.mass, ee.inertia.inertia)
        flange.add_body(name=END_EFFECTOR_BODY, pos=[0.0, 0.0, 0.0], mass=ee.mass,
                        ipos=np.array(ee.inertia.lever), iquat=quat, inertia=moments)
    flange.add_body(name=PAYLOAD_BODY, pos=[0.0, 0.0, 0.0], mass=0.0,
                    ipos=[0.0, 0.0, 0.0], inertia=[0.0, 0.0, 0.0])
    return spec.compile()
