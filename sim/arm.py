"""The arm as it is: link parameters, joint friction and torque offsets, and its file.

A real arm departs from its nominal model (its description, :mod:`sim.description`) in three
ways that show in the measured link-side torque ``tau_J``:

- its links' masses, CoMs and inertias differ by percents;
- joint friction (:mod:`sim.friction`): Coulomb friction in Gaz et al.'s sigmoid form
  (IEEE RA-L 2019, identified on ``tau_J``)::

      phi1 / (1 + exp(-phi2 (dq + phi3))) - phi1 / (1 + exp(-phi2 phi3))

  (zero at rest), plus viscous and Stribeck friction, each with its own coefficients for
  either direction of motion; a ``(7, 3)`` friction array is Gaz's model alone, a ``(7, 9)``
  one the full model;
- a constant offset per torque sensor.

:class:`ArmParams` holds one such arm: the seven joint bodies' dynamic parameters (Pinocchio
order ``[m, mcx, mcy, mcz, Ixx, Ixy, Iyy, Ixz, Iyz, Izz]``, in each joint's frame, inertia
about the joint origin; joint 7 includes the end effector), the friction per joint and the
offsets. The simulated arm's departure (:meth:`sim.reality_gap.RealityGap.realise`) and the one
identified from traffic (:mod:`sim.calibration`, ``iem calibrate``) are both an ArmParams, so
the plant, the tandem simulators and the estimators' regression use one arm model:
:class:`sim.robot.ArmModel` built with ``arm=`` gives
``tau_J = RNEA_arm(q, dq, ddq) + tau_f(dq) + offset``.

The arm file is the model file's format (:mod:`iem.persistence`: msgpack, schema
:data:`ARM_SCHEMA`, versioned, CRC32-checked, written atomically). Estimators name the arm
by content in their dynamics spec (:mod:`iem.physics.regression`, :mod:`iem.factories`):
``"sim.arm:arm_dynamics@arm:CRC32"`` (:func:`arm_spec`), the CRC32 of its state; the arm
itself is given at run time (``load_model(path, resources={"arm": arm})``), never named by
path.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, field, replace
from pathlib import Path as FsPath
from typing import ClassVar

import msgpack
import numpy as np

from iem.errors import InvalidInputError

from .description import (
    DEFAULT_ARM_MODEL,
    ArmDescription,
    arm_description,
    described,
    described_by,
)
from .friction import FRICTION_COLUMNS, GAZ_COLUMNS, FrictionPoints, friction_torque

ARM_SCHEMA = "iem-arm"
"""The ``schema`` field of an arm file."""

def _array(name: str, value, shape: tuple[int, ...]) -> np.ndarray:
    try:
        a = np.array(value, dtype=float).reshape(shape)
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(f"arm {name} must be {shape} numbers: {exc}") from exc
    if not np.all(np.isfinite(a)):
        raise InvalidInputError(f"arm {name} must be finite, got {a}")
    a.flags.writeable = False
    return a


def _friction_array(value) -> np.ndarray:
    try:
        a = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(f"arm friction must be numbers: {exc}") from exc
    if a.shape not in ((7, GAZ_COLUMNS), (7, len(FRICTION_COLUMNS))):
        raise InvalidInputError(f"arm friction must be (7, 3) (Gaz's phi1..3) or (7, 9) "
                                f"({', '.join(FRICTION_COLUMNS)}) per joint, got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise InvalidInputError(f"arm friction must be finite, got {a}")
    if a.shape[1] > GAZ_COLUMNS and np.any(a[:, 7:9] <= 0.0):
        raise InvalidInputError(f"arm friction's Stribeck velocities vs_pos, vs_neg must be "
                                f"> 0 rad/s, got {a[:, 7:9].tolist()}")
    a.flags.writeable = False
    return a

MAX_GAIN = 0.5
"""A torque sensor's relative gain error an arm file may hold, at most (exclusive)."""

POSTERIOR_PARAMS = 70 + 7 * len(FRICTION_COLUMNS)
"""The parameters :attr:`ArmParams.posterior` covers: the bodies' 70 and the friction's 63."""


def _posterior_array(value, friction: np.ndarray) -> np.ndarray:
    n = POSTERIOR_PARAMS
    a = _array("posterior", value, (n, n))
    if friction.shape[1] != len(FRICTION_COLUMNS):
        raise InvalidInputError(f"an arm posterior covers a (7, {len(FRICTION_COLUMNS)}) "
                                f"friction array, the arm has {friction.shape}")
    if not np.allclose(a, a.T, rtol=1e-9, atol=1e-15) or np.any(np.diag(a) < 0.0):
        raise InvalidInputError("arm posterior must be a symmetric covariance matrix with a "
                                "diagonal >= 0")
    return a


def _unpacked(packed) -> np.ndarray | None:
    """The covariance of :meth:`ArmParams.to_state`'s packed lower triangle (None: none)."""
    if packed is None:
        return None
    n = POSTERIOR_PARAMS
    flat = np.array(packed, dtype=float).reshape(-1)
    if flat.shape != (n * (n + 1) // 2,):
        raise InvalidInputError(f"arm posterior must be the {n * (n + 1) // 2} values of a "
                                f"{n}x{n} lower triangle, got {flat.shape[0]}")
    out = np.zeros((n, n))
    out[np.tril_indices(n)] = flat
    return out + np.tril(out, -1).T


@dataclass(frozen=True, eq=False)
class ArmParams:
    """One arm: its joint bodies, joint friction and torque-sensor offsets.

    Attributes:
        link_params: ``(7, 10)`` Pinocchio dynamic parameters of joint bodies 1..7 in their
            joint frames (kg, kg·m, kg·m² about the joint origin; body 7 holds link 7 and the
            end effector).
        friction: per joint, ``(7, 3)`` Gaz's ``phi1`` (N·m), ``phi2`` (s/rad), ``phi3``
            (rad/s), or ``(7, 9)`` those plus viscous and Stribeck friction per direction
            (:data:`FRICTION_COLUMNS`, :func:`friction_torque`); all zero: no friction. Kept
            as given, so an arm file keeps its state and CRC.
        offset: ``(7,)`` constant torque-sensor offsets, N·m.
        report: what made it (calibration figures: residual RMS, condition number, ...).
        end_effector: the label of the end effector body 7 carries
            (:mod:`sim.end_effector`: ``"franka_hand"``, ``"none"`` or a tool file's label).
        noise: what this arm model leaves unexplained in IEM+phys's equations
            (:class:`iem.physics.torque_noise.TorqueNoise` as a dict, measured by ``iem calibrate``
            on traffic it did not fit); None: not measured (the nominal arm's conservative
            default applies).
        source: the name of the arm file it was read from (:func:`load_arm`; not part of
            its state or CRC), for messages; None: made in memory.
        description: the arm model it is an instance of (:mod:`sim.description`; None: the
            default). Its state records it by content (name and digest), but for the default
            arm model: a file that records none was made for it.
        posterior: how sure the calibration that made it is: the posterior covariance
            (133x133) of ``link_params`` (raveled, 70) and ``friction`` (a ``(7, 9)`` one,
            raveled, 63), offsets marginalised (:mod:`sim.calibration.posterior`); None: not
            known (a nominal arm, a file from before it). An estimator carries it along
            its own poses (:class:`ArmDynamics`).
        armature: ``(7,)`` each joint's armature, kg·m²: its drive's reflected rotor
            inertia, a torque ``armature * ddq`` on its own joint (Pinocchio's
            ``Model.armature``; ``iem calibrate --armature``); zeros: none (Franka's
            link-side torque sensors see none).
        gain: ``(7,)`` each torque sensor's relative gain error (-): a payload's torque
            ``Y phi`` reads ``(1 + gain) Y phi`` (the bare arm's own torque is already
            what the sensors read: the calibration fits it as measured). Measured with a
            known load (``iem calibrate --known-load``); zeros: not measured.
    """

    link_params: np.ndarray
    friction: np.ndarray
    offset: np.ndarray
    report: dict = field(default_factory=dict)
    end_effector: str = "franka_hand"
    noise: dict | None = None
    source: str | None = field(default=None, repr=False)
    description: ArmDescription | None = field(default=None, repr=False)
    posterior: np.ndarray | None = field(default=None, repr=False)
    armature: np.ndarray | None = None
    gain: np.ndarray | None = None

    name: ClassVar[str] = "arm"
    """The kind recorded in the arm file."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "link_params", _array("link_params", self.link_params,
                                                       (7, 10)))
        object.__setattr__(self, "friction", _friction_array(self.friction))
        object.__setattr__(self, "offset", _array("offset", self.offset, (7,)))
        if self.description is None:
            object.__setattr__(self, "description", arm_description(None))
        if np.any(self.link_params[:, 0] <= 0.0):
            raise InvalidInputError(f"arm link masses must be > 0 kg, got "
                                    f"{self.link_params[:, 0]}")
        if self.posterior is not None:
            object.__setattr__(self, "posterior", _posterior_array(self.posterior,
                                                                   self.friction))
        object.__setattr__(self, "armature", _array(
            "armature", np.zeros(7) if self.armature is None else self.armature, (7,)))
        if np.any(self.armature < 0.0):
            raise InvalidInputError(f"arm armature must be >= 0 kg·m², got "
                                    f"{self.armature.tolist()}")
        object.__setattr__(self, "gain", _array(
            "gain", np.zeros(7) if self.gain is None else self.gain, (7,)))
        if np.any(np.abs(self.gain) >= MAX_GAIN):
            raise InvalidInputError(f"arm gain must be each joint's relative gain error, "
                                    f"between -{MAX_GAIN:g} and {MAX_GAIN:g}, got "
                                    f"{self.gain.tolist()}")

    @classmethod
    def nominal(cls, end_effector=None, description=None) -> ArmParams:
        """The nominal arm of ``description`` (an arm model's name, path or
        :class:`~sim.description.ArmDescription`; None: the default): its file's bodies with
        ``end_effector`` on body 7 (a spec or :class:`sim.end_effector.EndEffector`; None:
        the description's default), no friction, no offsets."""
        from .end_effector import end_effector_of
        from .robot import nominal_link_params

        desc = described(description)
        ee = end_effector_of(end_effector, desc)
        return cls(nominal_link_params(ee, desc), np.zeros((7, 3)), np.zeros(7),
                   {"source": "nominal"}, end_effector=ee.label, description=desc)

    def joint_torque(self, dq) -> np.ndarray:
        """Friction plus offset at ``dq`` (rad/s, ``(..., 7)``), N·m (one velocity's through
        :attr:`friction_points`: the same numbers)."""
        dq = np.asarray(dq, dtype=float)
        if dq.shape == (7,):
            return self.friction_points.torque(dq) + self.offset
        return friction_torque(dq, self.friction) + self.offset

    def __getstate__(self) -> dict:
        """A copy or a pickle carries the arm, not its friction's kept terms: a copy takes
        the one instance of its process (:meth:`FrictionPoints.of
        <sim.friction.FrictionPoints.of>`) on first use."""
        state = dict(self.__dict__)
        state.pop("_friction_points", None)
        return state

    @property
    def friction_points(self) -> FrictionPoints:
        """This arm's friction at single velocities (:class:`sim.friction.FrictionPoints`,
        shared by every copy of the arm in this process), taken on first use; not part of
        the arm's state."""
        points = self.__dict__.get("_friction_points")
        if points is None:
            points = FrictionPoints.of(self.friction)
            object.__setattr__(self, "_friction_points", points)
        return points

    # -- persistence -----------------------------------------------------------------------
    def to_state(self) -> dict:
        # the end effector and the noise only when set, so that an arm without them keeps
        # the state (and the CRC that model files record) it had before they existed
        state = {"link_params": self.link_params.tolist(), "friction": self.friction.tolist(),
                 "offset": self.offset.tolist(), "report": self.report}
        if self.end_effector != "franka_hand":
            state["end_effector"] = self.end_effector
        if self.noise is not None:
            state["noise"] = self.noise
        if self.description.name != DEFAULT_ARM_MODEL:
            state["description"] = self.description.record()
        if np.any(self.armature):  # only when fitted: an arm without keeps its CRC
            state["armature"] = self.armature.tolist()
        if np.any(self.gain):  # only when measured, as the armature
            state["gain"] = self.gain.tolist()
        if self.posterior is not None:  # its lower triangle, row by row
            state["posterior"] = self.posterior[np.tril_indices(POSTERIOR_PARAMS)].tolist()
        return state

    @classmethod
    def from_state(cls, state: dict) -> ArmParams:
        """The arm of ``state``, an instance of the arm model it records (none: the
        default; :func:`sim.description.described_by`)."""
        return cls(state["link_params"], state["friction"], state["offset"],
                   dict(state.get("report") or {}),
                   end_effector=str(state.get("end_effector") or "franka_hand"),
                   noise=state.get("noise"), description=described_by(state.get("description")),
                   posterior=_unpacked(state.get("posterior")),
                   armature=state.get("armature"), gain=state.get("gain"))

    @property
    def crc32(self) -> int:
        """CRC32 of the state, as the arm file records it: the arm's identity."""
        return zlib.crc32(msgpack.packb(self.to_state(), use_bin_type=True))

    def record(self) -> dict:
        """What a model file records of this arm (:func:`arm_record`; the
        :class:`iem.factories.Resource` protocol)."""
        return arm_record(self)


def save_arm(arm: ArmParams, path) -> None:
    """Write the arm file (atomically; :func:`iem.persistence.save_model`'s format)."""
    from iem.persistence import save_model

    save_model(arm, path, schema=ARM_SCHEMA, label="arm")


def load_arm(path, description=None) -> ArmParams:
    """The arm in the arm file ``path``, which must be an instance of the arm model
    ``description`` (None: any; :mod:`sim.description`).

    Raises:
        iem.errors.ModelFileError: missing, unreadable, corrupt or not an arm file.
        iem.errors.InvalidInputError: an arm of another arm model, naming both.
    """
    from iem.persistence import load_model

    arm = load_model(path, registry={ArmParams.name: "sim.arm:ArmParams"},
                     schema=ARM_SCHEMA, label="arm")
    if description is not None:
        want = described(description)
        if want.digest != arm.description.digest:
            raise InvalidInputError(
                f"arm model mismatch: the arm file {FsPath(path).name} is of the arm model "
                f"{arm.description.name!r} ({arm.description.digest}), the configuration's "
                f"is {want.name!r} ({want.digest}); set [arm] model (--arm-model) to the "
                f"arm's, or calibrate this arm with 'iem calibrate --arm-model {want.name}'")
    return replace(arm, source=FsPath(path).name)


def arm_record(arm: ArmParams | None, path=None) -> dict | None:
    """What a model file records of the arm it was trained for (None: the nominal arm with
    the Franka Hand). A nominal arm with another end effector (no file) is recorded as
    ``source`` "nominal"; the end effector is recorded when it is not the hand."""
    if arm is None:
        return None
    if path:
        source = FsPath(path).name
    elif arm.source:
        source = arm.source
    else:
        source = "nominal" if arm.report.get("source") == "nominal" else "<memory>"
    record = {"crc32": arm.crc32, "source": source}
    if arm.end_effector != "franka_hand":
        record["end_effector"] = arm.end_effector
    if arm.description.name != DEFAULT_ARM_MODEL:
        record["description"] = arm.description.record()
    return record


def arm_spec(arm: ArmParams) -> str:
    """The dynamics spec of ``arm`` for the estimators, ``"sim.arm:arm_dynamics@arm:CRC32"``
    (:mod:`iem.factories`: the arm by content, never by path); the arm is provided to this
    process's factories (:func:`iem.factories.provide`), so the spec can be built at once."""
    from iem.factories import provide

    return f"sim.arm:arm_dynamics@{provide('arm', arm)}"


class ArmDynamics:
    """``(q, dq, ddq) -> (tau_arm (7,), Y (7, 10), M (7, 7))`` of an arm: the torques of the
    arm without payload (friction and offsets included), the payload regressor, the arm's
    mass matrix; plus ``payload_mass_matrix(q, phi)`` (the fast path
    :class:`iem.physics.regression.PayloadRegression` uses when it is there).

    ``arm`` None: the nominal arm of the default arm model."""

    def __init__(self, arm: ArmParams | None = None) -> None:
        from .robot import ArmModel

        self.arm = arm
        self.model = ArmModel(arm=arm)
        self._factor = self._friction = None
        if arm is not None and arm.posterior is not None:
            ev, U = np.linalg.eigh(arm.posterior)
            keep = ev > 1e-12 * max(float(ev.max()), 1e-300)
            self._factor = U[:, keep] * np.sqrt(ev[keep])  # posterior = F F^T
            self._friction = arm.friction_points
            self._jac = np.zeros((7, POSTERIOR_PARAMS))  # [regressor | friction, per joint]
        self.considered = 0 if self._factor is None else int(self._factor.shape[1])
        """How many considered parameters :meth:`sensitivity` gives columns for (0: the arm
        carries no posterior)."""

    def __call__(self, q, dq, ddq):
        return self.model.rnea_regressor_mass(q, dq, ddq)

    @property
    def q_limits(self) -> tuple[np.ndarray, np.ndarray]:
        """The arm model's joint position limits ``(q_min, q_max)``, rad."""
        return self.model.q_min, self.model.q_max

    def sensitivity(self, q, dq, ddq) -> np.ndarray:
        """How the arm's torques at ``(q, dq, ddq)`` move per unit of its whitened
        calibration uncertainty: ``A F`` (7 x :attr:`considered`), ``A`` the Jacobian of the
        torques in the bodies' parameters and the friction, ``F F^T`` the arm's
        :attr:`ArmParams.posterior`. Unit-variance, uncorrelated parameters ``z`` then move
        the torques by ``A F z``, as the calibration's own uncertainty would."""
        jac = self._jac
        jac[:, :70] = self.model.joint_torque_regressor(q, dq, ddq)
        jac[_ROWS, _FRICTION_COLS] = self._friction.jacobian(np.asarray(dq, dtype=float))
        return jac @ self._factor

    def payload_mass_matrix(self, q, phi) -> np.ndarray:
        """The payload ``phi``'s share of the mass matrix at ``q``, ``J^T I_p J`` (7x7):
        one Jacobian instead of seven regressors."""
        return self.model.payload_mass_matrix(q, phi)


_ROWS = np.repeat(np.arange(7), len(FRICTION_COLUMNS)).reshape(7, -1)
_FRICTION_COLS = 70 + np.arange(7 * len(FRICTION_COLUMNS)).reshape(7, -1)
"""Where joint ``j``'s friction Jacobian goes in :meth:`ArmDynamics.sensitivity`'s rows."""


NOMINAL_DYNAMICS = "sim.arm:arm_dynamics"
"""The dynamics spec of the default arm model's nominal arm (:func:`arm_dynamics` of no arm),
which callers give the least-squares estimators (``dynamics=``;
:mod:`iem.physics.regression`) and model files store."""


def nominal_spec(end_effector, description=None) -> str:
    """The dynamics spec of the nominal arm of ``description`` (None: the default arm model)
    carrying ``end_effector`` (a name, or a tool file): on the default arm model a named one by
    its name, ``"sim.arm:nominal_dynamics@NAME"``; else by the content of that nominal arm
    (:func:`arm_spec`), never by a path."""
    from .end_effector import NAMED

    desc = described(description)
    spec = desc.end_effector_spec(end_effector)
    if spec in NAMED and desc.name == DEFAULT_ARM_MODEL:
        return f"sim.arm:nominal_dynamics@{spec}"
    return arm_spec(ArmParams.nominal(spec, desc))


def nominal_dynamics(end_effector: str | None = None) -> ArmDynamics:
    """The robot-model factory of ``"sim.arm:nominal_dynamics@NAME"``: the default arm model's
    nominal arm with the named end effector (:mod:`sim.end_effector`), no friction, no
    offsets."""
    return ArmDynamics(ArmParams.nominal(end_effector))


def arm_dynamics(arm: ArmParams | None = None) -> ArmDynamics:
    """The robot-model factory of ``"sim.arm:arm_dynamics@arm:CRC32"``: the arm given at run
    time with that content (:mod:`iem.factories`; none: the nominal arm)."""
    return ArmDynamics(arm)
