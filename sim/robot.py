"""The 7-DoF Panda in Pinocchio: kinematics, inverse dynamics and the payload regressor.

The model comes from example-robot-data's ``panda.urdf`` with the two finger joints locked
(``pinocchio.buildReducedModel``), so the hand is rigid and part of link 7. Frames:

- ``panda_link8``: the flange, Franka's frame F in which ``F_x_Cload`` is given;
- ``panda_hand_tcp``: the tool centre point of the Franka Hand.

A payload is a rigid body fixed to the flange. Its parameters ``phi`` (paper order, inertia
about the flange origin) enter the joint torques linearly: ``tau_payload = Y(q, dq, ddq) @ phi``.
"""

from __future__ import annotations

import site
import sys
from functools import cache
from pathlib import Path as FsPath

import numpy as np
import pinocchio as pin

FLANGE_FRAME = "panda_link8"
TCP_FRAME = "panda_hand_tcp"

# Franka Emika Panda datasheet limits (joint 1..7).
DQ_MAX = np.array([2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61])  # rad/s
DDQ_MAX = np.array([15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0])  # rad/s²
TAU_MAX = np.array([87.0, 87.0, 87.0, 87.0, 12.0, 12.0, 12.0])  # N·m

# Paper order [m, mrx, mry, mrz, Ixx, Ixy, Ixz, Iyy, Iyz, Izz] -> Pinocchio's dynamic
# parameter order [m, mcx, mcy, mcz, Ixx, Ixy, Iyy, Ixz, Iyz, Izz].
PAPER_TO_PIN = np.array([0, 1, 2, 3, 4, 5, 7, 6, 8, 9])
"""``phi_pin = phi_paper[PAPER_TO_PIN]``, ``phi_paper = phi_pin[PAPER_TO_PIN]`` (involution)."""


@cache
def panda_description_dir() -> FsPath:
    """Folder of example-robot-data's Panda description (under the cmeel prefix)."""
    roots = [*site.getsitepackages(), site.getusersitepackages(), *sys.path]
    for root in roots:
        cand = FsPath(root) / "cmeel.prefix/share/example-robot-data/robots/panda_description"
        if (cand / "urdf/panda.urdf").is_file():
            return cand
    raise FileNotFoundError(
        "example-robot-data's panda.urdf not found under any site-packages "
        "'cmeel.prefix/share/example-robot-data/robots/panda_description/urdf'; "
        "install the package example-robot-data"
    )


def panda_urdf(collision: bool = False) -> FsPath:
    """Path of ``panda.urdf`` (or ``panda_collision.urdf``, which MuJoCo can load)."""
    name = "panda_collision.urdf" if collision else "panda.urdf"
    return panda_description_dir() / "urdf" / name


def phi_to_pin(phi: np.ndarray) -> np.ndarray:
    """Paper order -> Pinocchio dynamic-parameter order (works on ``(..., 10)`` arrays)."""
    return np.asarray(phi)[..., PAPER_TO_PIN]


def _nominal_model() -> pin.Model:
    full = pin.buildModelFromUrdf(str(panda_urdf()))
    locked = [full.getJointId(n) for n in ("panda_finger_joint1", "panda_finger_joint2")]
    return pin.buildReducedModel(full, locked, pin.neutral(full))


def nominal_link_params(end_effector=None) -> np.ndarray:
    """``(7, 10)`` Pinocchio dynamic parameters of the nominal joint bodies 1..7, body 7
    carrying ``end_effector`` (a :class:`sim.end_effector.EndEffector` or its spec; None:
    the URDF's Franka Hand)."""
    model = _nominal_model()
    out = np.array([model.inertias[j].toDynamicParameters() for j in range(1, 8)])
    if end_effector is not None:
        from .end_effector import EndEffector
        from .end_effector import end_effector as resolve

        ee = end_effector if isinstance(end_effector, EndEffector) else resolve(end_effector)
        if ee.spec != "franka_hand":
            out[6] = ee.body7()
    return out


@cache
def flange_placement() -> pin.SE3:
    """The flange frame (``panda_link8``) in the joint-7 frame."""
    model = _nominal_model()
    return model.frames[model.getFrameId(FLANGE_FRAME)].placement.copy()


class PandaModel:
    """Pinocchio model of the 7-DoF Panda (fingers locked, hand rigid) with the flange frame.

    Args:
        arm: the arm's own bodies, friction and offsets (:class:`sim.arm.ArmParams`); None:
            the nominal arm (the URDF's bodies, no friction, no offsets). With an arm, every
            torque this model gives (``rnea``, ``rnea_with_payload``,
            ``rnea_and_regressor``) is the measured ``tau_J`` of that arm: its bodies' RNEA
            plus friction plus offsets; the payload regressor depends only on kinematics.

    Not thread-safe: it owns one Pinocchio ``Data``. Make one per thread.
    """

    nq = 7

    def __init__(self, arm=None) -> None:
        self.model = _nominal_model()
        self.arm = arm
        if arm is not None:
            for j in range(1, 8):
                self.model.inertias[j] = pin.Inertia.FromDynamicParameters(
                    np.asarray(arm.link_params[j - 1], dtype=float))
        self._extra = None if arm is None else arm.joint_torque
        self.data = self.model.createData()
        self.flange_id = self.model.getFrameId(FLANGE_FRAME)
        self.tcp_id = self.model.getFrameId(TCP_FRAME)
        self.last_joint = self.model.frames[self.flange_id].parentJoint
        self.flange_placement = self.model.frames[self.flange_id].placement.copy()
        self.q_min = self.model.lowerPositionLimit.copy()
        self.q_max = self.model.upperPositionLimit.copy()
        self.dq_max = DQ_MAX.copy()
        self.ddq_max = DDQ_MAX.copy()
        self.tau_max = TAU_MAX.copy()
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
        tau = pin.rnea(self._pl_model, self._pl_data, np.asarray(q, float),
                       np.asarray(dq, float), np.asarray(ddq, float)).copy()
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
        return tau, (jac.T @ body)[:, PAPER_TO_PIN]

    def rnea_regressor_mass(self, q, dq, ddq):
        """:meth:`rnea_and_regressor` plus the arm's mass matrix ``M(q)`` (7x7, CRBA)."""
        tau, y = self.rnea_and_regressor(q, dq, ddq)
        mass = pin.crba(self.model, self.data, np.asarray(q, dtype=float))
        mass = np.triu(mass) + np.triu(mass, 1).T
        return tau, y, mass

    def payload_mass_matrix(self, q, phi) -> np.ndarray:
        """The payload's share of the joint-space mass matrix, ``J^T I_p J`` (7x7), for the
        payload ``phi`` (paper order) on the flange; ``J`` the flange Jacobian (LOCAL)."""
        q = np.asarray(q, dtype=float)
        jac = pin.computeFrameJacobian(self.model, self.data, q, self.flange_id, pin.LOCAL)
        return jac.T @ spatial_inertia(phi) @ jac

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
    m, hx, hy, hz, ixx, ixy, ixz, iyy, iyz, izz = (float(v) for v in np.asarray(phi))
    skew = np.array([[0.0, -hz, hy], [hz, 0.0, -hx], [-hy, hx, 0.0]])
    out = np.zeros((6, 6))
    out[:3, :3] = m * np.eye(3)
    out[:3, 3:] = -skew
    out[3:, :3] = skew
    out[3:, 3:] = [[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]]
    return out


class PandaDynamics:
    """``(q, dq, ddq) -> (tau_robot, Y, M)`` of a nominal Panda (:meth:`PandaModel.
    rnea_regressor_mass`), plus the payload's mass matrix ``payload_mass_matrix(q, phi)``
    (the fast path :class:`iem.physics.regression.PayloadRegression` uses when it is there)."""

    def __init__(self) -> None:
        self.model = PandaModel()

    def __call__(self, q, dq, ddq):
        return self.model.rnea_regressor_mass(q, dq, ddq)

    def payload_mass_matrix(self, q, phi) -> np.ndarray:
        return self.model.payload_mass_matrix(q, phi)


def panda_dynamics() -> PandaDynamics:
    """The robot-model factory of :data:`PANDA_DYNAMICS`; each call builds its own model,
    since a model owns its scratch data."""
    return PandaDynamics()


PANDA_DYNAMICS = "sim.robot:panda_dynamics"
"""The dynamics spec of the nominal Panda (:func:`panda_dynamics`), which callers give the
least-squares estimators (``dynamics=``; :mod:`iem.physics.regression`) and model files store."""


@cache
def panda() -> PandaModel:
    """A shared nominal Panda model (loading the URDF takes a few ms)."""
    return PandaModel()
