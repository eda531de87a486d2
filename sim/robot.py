"""The 7-joint arm in Pinocchio: kinematics, inverse dynamics and the payload regressor.

The model comes from the arm's description (:mod:`sim.description`: ``[arm] model``, the
Panda by default). Bodies 1..7 are the seven arm joints' bodies; body 7 carries the end
effector (:mod:`sim.end_effector`), fixed to the flange frame (the Panda's ``panda_link8``,
the FR3's ``fr3_link8``: Franka's frame F, in which ``F_x_Cload`` is given).

A payload is a rigid body fixed to the flange. Its parameters ``phi`` (paper order, inertia
about the flange origin) enter the joint torques linearly: ``tau_payload = Y(q, dq, ddq) @ phi``.
"""

from __future__ import annotations

from functools import cache

import numpy as np
import pinocchio as pin

from .description import described
from .nominal import nominal_model

# Paper order [m, mrx, mry, mrz, Ixx, Ixy, Ixz, Iyy, Iyz, Izz] -> Pinocchio's dynamic
# parameter order [m, mcx, mcy, mcz, Ixx, Ixy, Iyy, Ixz, Iyz, Izz].
PAPER_TO_PIN = np.array([0, 1, 2, 3, 4, 5, 7, 6, 8, 9])
"""``phi_pin = phi_paper[PAPER_TO_PIN]``, ``phi_paper = phi_pin[PAPER_TO_PIN]`` (involution)."""


_LOWER, _UPPER = (np.array([i * 7 + j for i in range(7) for j in range(i)]),
                  np.array([j * 7 + i for i in range(7) for j in range(i)]))
"""Flat indices of a 7x7 matrix's strict lower triangle and of its mirror in the upper."""


def phi_to_pin(phi: np.ndarray) -> np.ndarray:
    """Paper order -> Pinocchio dynamic-parameter order (works on ``(..., 10)`` arrays)."""
    return np.asarray(phi)[..., PAPER_TO_PIN]


def nominal_link_params(end_effector=None, description=None) -> np.ndarray:
    """``(7, 10)`` Pinocchio dynamic parameters of the nominal joint bodies 1..7 of the arm
    ``description`` (None: the default arm model), body 7 carrying ``end_effector`` (a
    :class:`sim.end_effector.EndEffector` or its spec; None: the description's default)."""
    from .end_effector import end_effector_of

    desc = described(description)
    model = nominal_model(desc)
    out = np.array([model.inertias[j].toDynamicParameters() for j in range(1, 8)])
    ee = end_effector_of(end_effector, desc)
    if not desc.carries_own(ee.spec):
        out[6] = ee.body7(desc)
    return out


class ArmModel:
    """Pinocchio model of the 7-joint arm with the flange frame.

    Args:
        arm: the arm's own bodies, friction and offsets (:class:`sim.arm.ArmParams`, which
            names its description); None: the nominal arm of ``description`` (the file's
            bodies with its default end effector, no friction, no offsets). With an arm,
            every torque this model gives (``rnea``, ``rnea_with_payload``,
            ``rnea_and_regressor``) is the measured ``tau_J`` of that arm: its bodies' RNEA
            (with its armature) plus friction plus offsets; the payload regressor depends
            on kinematics and, where the arm has measured its sensors' gain
            (:attr:`sim.arm.ArmParams.gain`), reads a payload's torque through it, as do the
            payload's share of ``rnea_with_payload`` and ``payload_mass_matrix``.
        description: the arm model (:mod:`sim.description`; a name, a path or an
            :class:`~sim.description.ArmDescription`) when ``arm`` is None; None: the
            default.

    Not thread-safe: it owns one Pinocchio ``Data``. Make one per thread.
    """

    nq = 7

    def __init__(self, arm=None, description=None) -> None:
        self.description = arm.description if arm is not None else described(description)
        self.model = nominal_model(self.description).copy()
        self.arm = arm
        if arm is not None:
            for j in range(1, 8):
                self.model.inertias[j] = pin.Inertia.FromDynamicParameters(
                    np.asarray(arm.link_params[j - 1], dtype=float))
            self.model.armature = np.asarray(arm.armature, dtype=float)  # in rnea and crba
        elif not self.description.carries_own(None):  # the end effector on body 7
            self.model.inertias[7] = pin.Inertia.FromDynamicParameters(
                nominal_link_params(None, self.description)[6])
        self._extra = None if arm is None else arm.joint_torque
        # the torque sensors' gain on a payload's torque (None: not measured)
        self._gain = None if arm is None or not np.any(arm.gain) else 1.0 + arm.gain
        self.data = self.model.createData()
        self.flange_id = self.model.getFrameId(self.description.flange)
        self.last_joint = self.model.frames[self.flange_id].parentJoint
        self.flange_placement = self.model.frames[self.flange_id].placement.copy()
        limits = self.description.limits
        self.q_min = limits.q_min.copy()
        self.q_max = limits.q_max.copy()
        self.dq_max = limits.dq_max.copy()
        self.ddq_max = limits.ddq_max.copy()
        self.tau_max = limits.tau_max.copy()
        self._link7 = self.model.inertias[self.last_joint].copy()
        # model with a payload body at the flange (its inertia is set by set_payload_phi)
        self._pl_model = self.model.copy()
        self._pl_data = self._pl_model.createData()
        self._pl_phi = np.zeros(10)

    # -- kinematics ------------------------------------------------------------------------
    def flange_position(self, q) -> np.ndarray:
        """Flange origin in the base frame, m."""
        pin.forwardKinematics(self.model, self.data, np.asarray(q, dtype=float))
        # only the flange's frame (all frames cost twice as much; the online cycle asks this)
        return pin.updateFramePlacement(self.model, self.data, self.flange_id).translation.copy()

    def flange_positions(self, Q) -> np.ndarray:
        """Flange positions for many configurations, ``(N, 7) -> (N, 3)``."""
        Q = np.asarray(Q, dtype=float)
        out = np.empty((Q.shape[0], 3))
        for i, q in enumerate(Q):
            pin.framesForwardKinematics(self.model, self.data, q)
            out[i] = self.data.oMf[self.flange_id].translation
        return out

    # -- dynamics --------------------------------------------------------------------------
    def rnea(self, q, dq, ddq) -> np.ndarray:
        """Joint torques of the arm without payload, N·m."""
        tau = pin.rnea(self.model, self.data, np.asarray(q, float), np.asarray(dq, float),
                       np.asarray(ddq, float)).copy()
        return tau if self._extra is None else tau + self._extra(dq)

    def payload_inertia_in_joint(self, phi) -> pin.Inertia:
        """The payload (paper phi at the flange) as a Pinocchio inertia in the joint-7 frame."""
        return self.flange_placement.act(pin.Inertia.FromDynamicParameters(phi_to_pin(phi)))

    def rnea_with_payload(self, q, dq, ddq, phi) -> np.ndarray:
        """Joint torques with the payload ``phi`` (paper order) rigidly on the flange, N·m."""
        phi = np.asarray(phi, dtype=float)
        if not np.array_equal(phi, self._pl_phi):
            self._pl_model.inertias[self.last_joint] = (
                self._link7 + self.payload_inertia_in_joint(phi))
            self._pl_phi = phi.copy()
        q, dq, ddq = (np.asarray(v, float) for v in (q, dq, ddq))
        tau = pin.rnea(self._pl_model, self._pl_data, q, dq, ddq).copy()
        if self._gain is not None:  # the payload's share as the arm's sensors read it
            bare = pin.rnea(self.model, self.data, q, dq, ddq)
            tau = bare + self._gain * (tau - bare)
        return tau if self._extra is None else tau + self._extra(dq)

    def payload_regressor(self, q, dq, ddq) -> np.ndarray:
        """``Y`` (7x10) with ``tau_payload = Y @ phi``, phi in the paper's order.

        Pinocchio's body regressor of the flange frame gives the wrench a body at the flange
        needs for the motion (gravity included); the flange Jacobian maps it to joint torques.
        """
        return self.rnea_and_regressor(q, dq, ddq)[1]

    def rnea_and_regressor(self, q, dq, ddq) -> tuple[np.ndarray, np.ndarray]:
        """Both the payload-free torques and ``Y`` from one RNEA pass (the tandem hot path)."""
        q = np.asarray(q, dtype=float)
        tau = pin.rnea(self.model, self.data, q, np.asarray(dq, float),
                       np.asarray(ddq, float)).copy()
        body = pin.frameBodyRegressor(self.model, self.data, self.flange_id)
        jac = pin.computeFrameJacobian(self.model, self.data, q, self.flange_id, pin.LOCAL)
        if self._extra is not None:
            tau += self._extra(dq)
        regressor = (jac.T @ body)[:, PAPER_TO_PIN]
        if self._gain is not None:  # as the arm's sensors read a payload's torque
            regressor *= self._gain[:, None]
        return tau, regressor

    def joint_torque_regressor(self, q, dq, ddq) -> np.ndarray:
        """The joint torques' regressor in the seven bodies' parameters (7x70, Pinocchio
        order, bodies in their joint frames): ``rnea = W theta`` without friction and
        offsets."""
        return pin.computeJointTorqueRegressor(self.model, self.data, np.asarray(q, float),
                                               np.asarray(dq, float),
                                               np.asarray(ddq, float)).copy()

    def rnea_regressor_mass(self, q, dq, ddq):
        """:meth:`rnea_and_regressor` plus the arm's mass matrix ``M(q)`` (7x7, CRBA)."""
        tau, y = self.rnea_and_regressor(q, dq, ddq)
        # CRBA fills the upper triangle; the lower is its mirror (``+ 0.0`` copies it and
        # reads a -0.0 as 0.0, as a sum of the two triangles would)
        mass = pin.crba(self.model, self.data, np.asarray(q, dtype=float)) + 0.0
        flat = mass.reshape(-1)
        flat[_LOWER] = flat[_UPPER]
        return tau, y, mass

    def payload_mass_matrix(self, q, phi) -> np.ndarray:
        """The payload's share of the joint-space mass matrix, ``J^T I_p J`` (7x7), for the
        payload ``phi`` (paper order) on the flange; ``J`` the flange Jacobian (LOCAL)."""
        q = np.asarray(q, dtype=float)
        jac = pin.computeFrameJacobian(self.model, self.data, q, self.flange_id, pin.LOCAL)
        mass = jac.T @ spatial_inertia(phi) @ jac
        return mass if self._gain is None else mass * self._gain[:, None]

    # -- checks ----------------------------------------------------------------------------
    def random_state(self, rng: np.random.Generator, margin: float = 0.0):
        """A random (q, dq, ddq) inside the position, velocity and acceleration limits."""
        span = self.q_max - self.q_min
        q = rng.uniform(self.q_min + margin * span, self.q_max - margin * span)
        dq = rng.uniform(-self.dq_max, self.dq_max)
        ddq = rng.uniform(-self.ddq_max, self.ddq_max)
        return q, dq, ddq


def spatial_inertia(phi) -> np.ndarray:
    """The 6x6 spatial inertia at the flange origin, ``[[m E, -S(h)], [S(h), I_o]]`` in
    Pinocchio's ``[linear; angular]`` order, from ``phi`` (paper order). Linear in ``phi``, so
    it exists for any values (``pin.Inertia`` needs ``m > 0`` to place the CoM)."""
    m, hx, hy, hz, ixx, ixy, ixz, iyy, iyz, izz = np.asarray(phi, dtype=float).tolist()
    z = m * 0.0  # m E's off-diagonal (-0.0 for a negative m); -S(h)'s diagonal is -0.0
    return np.array([[m, z, z, -0.0, hz, -hy],
                     [z, m, z, -hz, -0.0, hx],
                     [z, z, m, hy, -hx, -0.0],
                     [0.0, -hz, hy, ixx, ixy, ixz],
                     [hz, 0.0, -hx, ixy, iyy, iyz],
                     [-hy, hx, 0.0, ixz, iyz, izz]])


@cache
def arm_model(description=None) -> ArmModel:
    """A shared nominal model of the arm ``description`` (None: the default arm model; loading
    a description takes a few ms)."""
    return ArmModel(description=description)
