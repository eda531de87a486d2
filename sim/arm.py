"""The arm as it is: link parameters, joint friction and torque offsets, and its file.

A real Panda departs from its nominal model (example-robot-data's URDF) in three ways that
show in the measured link-side torque ``tau_J``:

- its links' masses, CoMs and inertias differ by percents;
- joint friction, in Gaz et al.'s form (IEEE RA-L 2019, identified on ``tau_J``)::

      tau_f = phi1 / (1 + exp(-phi2 (dq + phi3))) - phi1 / (1 + exp(-phi2 phi3))

  (:func:`gaz_friction`, zero at rest; :data:`GAZ_PHI` their values);
- a constant offset per torque sensor.

:class:`ArmParams` holds one such arm: the seven joint bodies' dynamic parameters (Pinocchio
order ``[m, mcx, mcy, mcz, Ixx, Ixy, Iyy, Ixz, Iyz, Izz]``, in each joint's frame, inertia
about the joint origin; joint 7 includes the hand), the friction ``phi1..3`` per joint and the
offsets. The simulated arm's departure (:meth:`sim.plant.RealityGap.realise`) and the one
identified from traffic (:mod:`sim.calibration`, ``iem calibrate``) are both an ArmParams, so
the plant, the tandem simulators and the estimators' regression use one arm model:
:class:`sim.robot.PandaModel` built with ``arm=`` gives
``tau_J = RNEA_arm(q, dq, ddq) + tau_f(dq) + offset``.

The arm file is the model file's format (:mod:`iem.persistence`: msgpack, schema
:data:`ARM_SCHEMA`, versioned, CRC32-checked, written atomically). Estimators name the arm
by their dynamics spec (:mod:`iem.regression`): ``"sim.arm:arm_dynamics@/path/arm.msgpack"``.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, field
from pathlib import Path as FsPath
from typing import ClassVar

import msgpack
import numpy as np

from iem.errors import InvalidInputError

ARM_SCHEMA = "iem-arm"
"""The ``schema`` field of an arm file."""

GAZ_PHI = np.array([
    [0.546, 0.872, 0.641, 1.279, 0.839, 0.303, 0.565],  # phi1, N·m
    [5.12, 9.07, 10.14, 5.59, 8.35, 17.13, 10.34],  # phi2, s/rad
    [0.0395, 0.0259, -0.0461, 0.0362, 0.0262, -0.0210, 0.0036],  # phi3, rad/s
]).T
"""Gaz et al.'s friction parameters, ``(7, 3)``: ``phi1`` (N·m), ``phi2`` (s/rad),
``phi3`` (rad/s) per joint."""
GAZ_PHI.flags.writeable = False


def _sigmoid(x):
    return 0.5 * (1.0 + np.tanh(0.5 * x))  # 1 / (1 + exp(-x)), without overflow


def gaz_friction(dq, phi) -> np.ndarray:
    """Friction torque of Gaz's model, N·m, at joint velocities ``dq`` (``(..., 7)``, rad/s),
    with ``phi`` ``(7, 3)`` = ``[phi1, phi2, phi3]`` per joint; zero at ``dq = 0``."""
    phi = np.asarray(phi, dtype=float)
    p1, p2, p3 = phi[:, 0], phi[:, 1], phi[:, 2]
    return p1 * (_sigmoid(p2 * (np.asarray(dq, dtype=float) + p3)) - _sigmoid(p2 * p3))


def gaz_friction_jacobian(dq, phi) -> np.ndarray:
    """``d tau_f / d phi`` at ``dq`` ``(N, 7)``: ``(N, 7, 3)`` (phi1, phi2, phi3 columns)."""
    phi = np.asarray(phi, dtype=float)
    p1, p2, p3 = phi[:, 0], phi[:, 1], phi[:, 2]
    dq = np.asarray(dq, dtype=float)
    s = _sigmoid(p2 * (dq + p3))
    s0 = _sigmoid(p2 * p3)
    ds, ds0 = s * (1.0 - s), s0 * (1.0 - s0)
    out = np.empty((*dq.shape, 3))
    out[..., 0] = s - s0
    out[..., 1] = p1 * (ds * (dq + p3) - ds0 * p3)
    out[..., 2] = p1 * p2 * (ds - ds0)
    return out


def _array(name: str, value, shape: tuple[int, ...]) -> np.ndarray:
    try:
        a = np.array(value, dtype=float).reshape(shape)
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(f"arm {name} must be {shape} numbers: {exc}") from exc
    if not np.all(np.isfinite(a)):
        raise InvalidInputError(f"arm {name} must be finite, got {a}")
    a.flags.writeable = False
    return a


@dataclass(frozen=True, eq=False)
class ArmParams:
    """One arm: its joint bodies, joint friction and torque-sensor offsets.

    Attributes:
        link_params: ``(7, 10)`` Pinocchio dynamic parameters of joint bodies 1..7 in their
            joint frames (kg, kg·m, kg·m² about the joint origin; body 7 holds link 7 and the
            hand).
        friction: ``(7, 3)`` Gaz's ``phi1`` (N·m), ``phi2`` (s/rad), ``phi3`` (rad/s) per
            joint; zero ``phi1``: no friction.
        offset: ``(7,)`` constant torque-sensor offsets, N·m.
        report: what made it (calibration figures: residual RMS, condition number, ...).
    """

    link_params: np.ndarray
    friction: np.ndarray
    offset: np.ndarray
    report: dict = field(default_factory=dict)

    name: ClassVar[str] = "arm"
    """The kind recorded in the arm file."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "link_params", _array("link_params", self.link_params,
                                                       (7, 10)))
        object.__setattr__(self, "friction", _array("friction", self.friction, (7, 3)))
        object.__setattr__(self, "offset", _array("offset", self.offset, (7,)))
        if np.any(self.link_params[:, 0] <= 0.0):
            raise InvalidInputError(f"arm link masses must be > 0 kg, got "
                                    f"{self.link_params[:, 0]}")

    @classmethod
    def nominal(cls) -> ArmParams:
        """The nominal Panda: the URDF's bodies, no friction, no offsets."""
        from .robot import nominal_link_params

        return cls(nominal_link_params(), np.zeros((7, 3)), np.zeros(7),
                   {"source": "nominal"})

    def joint_torque(self, dq) -> np.ndarray:
        """Friction plus offset at ``dq`` (rad/s, ``(..., 7)``), N·m."""
        return gaz_friction(dq, self.friction) + self.offset

    # -- persistence -----------------------------------------------------------------------
    def to_state(self) -> dict:
        return {"link_params": self.link_params.tolist(), "friction": self.friction.tolist(),
                "offset": self.offset.tolist(), "report": self.report}

    @classmethod
    def from_state(cls, state: dict) -> ArmParams:
        return cls(state["link_params"], state["friction"], state["offset"],
                   dict(state.get("report") or {}))

    @property
    def crc32(self) -> int:
        """CRC32 of the state, as the arm file records it: the arm's identity."""
        return zlib.crc32(msgpack.packb(self.to_state(), use_bin_type=True))


def save_arm(arm: ArmParams, path) -> None:
    """Write the arm file (atomically; :func:`iem.persistence.save_model`'s format)."""
    from iem.persistence import save_model

    save_model(arm, path, schema=ARM_SCHEMA, label="arm")


def load_arm(path) -> ArmParams:
    """The arm in the arm file ``path``.

    Raises:
        iem.errors.ModelFileError: missing, unreadable, corrupt or not an arm file.
    """
    from iem.persistence import load_model

    return load_model(path, registry={ArmParams.name: "sim.arm:ArmParams"},
                      schema=ARM_SCHEMA, label="arm")


def arm_record(arm: ArmParams | None, path=None) -> dict | None:
    """What a model file records of the arm it was trained for (None: nominal)."""
    if arm is None:
        return None
    return {"crc32": arm.crc32, "source": FsPath(path).name if path else "<memory>"}


def arm_spec(path) -> str:
    """The dynamics spec that names the arm file ``path`` (absolute) for the estimators."""
    return f"sim.arm:arm_dynamics@{FsPath(path).resolve()}"


class ArmDynamics:
    """``(q, dq, ddq) -> (tau_arm (7,), Y (7, 10), M (7, 7))`` of an arm: the torques of the
    arm without payload (friction and offsets included), the payload regressor, the arm's
    mass matrix; plus ``payload_mass_matrix(q, phi)`` (as :class:`sim.robot.PandaDynamics`)."""

    def __init__(self, arm: ArmParams | None = None) -> None:
        from .robot import PandaModel

        self.arm = arm
        self.model = PandaModel(arm=arm)

    def __call__(self, q, dq, ddq):
        return self.model.rnea_regressor_mass(q, dq, ddq)

    def payload_mass_matrix(self, q, phi) -> np.ndarray:
        return self.model.payload_mass_matrix(q, phi)


def arm_dynamics(path: str | None = None) -> ArmDynamics:
    """The robot-model factory of the dynamics spec ``"sim.arm:arm_dynamics@PATH"``: the arm
    of the arm file ``PATH`` (no path: the nominal arm)."""
    return ArmDynamics(None if path is None else load_arm(path))
