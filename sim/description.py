"""The arm's description: one file that gives the Pinocchio model, the MuJoCo plant, the joint
names, the joint limits, the flange frame and the rated payload.

``[arm] model`` in ``cell.toml`` (``--arm-model`` on the commands) names it once:

- ``"panda"``: example-robot-data's ``panda.urdf`` (the Franka Emika Panda, FER), whose
  Franka Hand is the ``franka_hand`` end effector;
- ``"fr3"``: the Franka Research 3 of franka_description (Apache-2.0, Franka Robotics GmbH),
  as the package franky-sim ships it (``fr3_clean.urdf``: franka_description's kinematics,
  inertials, velocity and torque limits, without meshes), with the position limits of
  franka_description's ``joint_limits.yaml`` (the datasheet's; the file's are wider) and its
  ``fr3_`` prefix on the joints and links;
- a path to a URDF of another arm, with ``[arm] flange`` naming its flange link if the file
  does not tell it. An MJCF is refused with that said: the chain's checks, its limits and
  the pruning beyond the flange are written against URDF only.

A description is read without meshes: every ``<visual>`` and ``<collision>`` is dropped, so a
mesh path that does not resolve costs nothing. The arm is the seven revolute joints on the way
from the root to the flange; a joint that is not on it must hang beyond the flange (a
gripper's fingers), where it is locked and, with everything else beyond the flange, left out:
what the flange carries is ``[arm] end_effector``'s. A ``continuous`` joint is taken as
revolute within one turn either way (±π). Every body a joint moves must have an
``<inertial>`` with a mass.

The description is known by its content: :attr:`ArmDescription.digest` (SHA-256 of the text
read and the flange), which arm files and model files record.
"""

from __future__ import annotations

import hashlib
import site
import sys
from dataclasses import dataclass, field
from functools import cache
from importlib.util import find_spec
from pathlib import Path as FsPath

import numpy as np

from iem.errors import InvalidInputError
from iem.user_files import read_text

from .urdf_chain import arm_error, joint_limit, parse, read_urdf

MAX_URDF_BYTES = 16 * 1024 * 1024
"""Largest arm description file read (a URDF is kilobytes; its meshes are files of their
own)."""

DEFAULT_ARM_MODEL = "panda"
"""The arm model of a configuration that names none."""


@dataclass(frozen=True)
class Limits:
    """The arm's joint limits (joint 1..7): position (rad), velocity (rad/s), acceleration
    (rad/s²) and torque (N·m)."""

    q_min: np.ndarray
    q_max: np.ndarray
    dq_max: np.ndarray
    ddq_max: np.ndarray
    tau_max: np.ndarray


@dataclass(frozen=True)
class BuiltinArm:
    """What a named arm adds to its file: where the file is, the datasheet's limits the file
    lacks and the rated payload."""

    flange: str
    rated_payload_kg: float
    ddq_max: tuple[float, ...]
    dq_max: tuple[float, ...] | None = None
    """Velocity limits (None: the file's)."""
    q_limits: tuple[tuple[float, ...], tuple[float, ...]] | None = None
    """Position limits, lower and upper (None: the file's)."""
    home: tuple[float, ...] | None = None
    """The configuration the paths move around (None: :func:`default_home`)."""
    task: tuple[tuple[float, ...], tuple[float, ...]] | None = None
    """The new task path's ends (None: :func:`default_task`)."""
    default_end_effector: str = "franka_hand"
    own_end_effector: str | None = None
    """The end effector the file itself carries beyond the flange (None: none kept)."""
    prefix: str = ""
    """Prefix added to every joint and link name of the file (franka_description's arm id)."""


_PANDA_HOME = (0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.8)
_PANDA_TASK = ((-1.0, 0.2, 0.5, -1.6, 0.5, 1.6, 0.0), (1.2, 0.4, -0.6, -1.4, 0.7, 2.6, -0.5))
BUILTINS = {
    # Franka Emika Panda datasheet (joint 1..7)
    "panda": BuiltinArm(flange="panda_link8", rated_payload_kg=3.0,
                        dq_max=(2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61),
                        ddq_max=(15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0), home=_PANDA_HOME,
                        task=_PANDA_TASK, own_end_effector="franka_hand"),
    # Franka Research 3 datasheet: 3 kg, 10 rad/s² on every joint; the file's velocities;
    # the positions of franka_description's robots/fr3/joint_limits.yaml, the datasheet's
    # (fr3_clean.urdf's own position limits are wider, beyond what the robot accepts)
    "fr3": BuiltinArm(flange="fr3_link8", rated_payload_kg=3.0, ddq_max=(10.0,) * 7,
                      q_limits=((-2.7437, -1.7837, -2.9007, -3.0421, -2.8065, 0.5445, -3.0159),
                                (2.7437, 1.7837, 2.9007, -0.1518, 2.8065, 4.5169, 3.0159)),
                      home=_PANDA_HOME, task=_PANDA_TASK, prefix="fr3_"),
}
BUILTIN = tuple(BUILTINS)
"""Arm models known by name; anything else is a description file's path."""


@dataclass(frozen=True, eq=False)
class ArmDescription:
    """One arm's description, read and checked (:func:`arm_description`).

    Attributes:
        name: "panda", "fr3", or the file's name.
        source: where it was read from (a path), for messages.
        text: the description as both Pinocchio and MuJoCo read it (URDF: without visuals,
            collisions and anything beyond the flange, continuous joints made revolute).
        full_text: the same with what hangs beyond the flange (the Panda's hand).
        flange: the flange link (body), the frame payloads and end effectors attach to.
        joint_names: the seven arm joints, root to flange.
        link_bodies: the bodies (links) each joint moves, the joint's child link.
        limits: :class:`Limits`.
        rated_payload_kg: the maker's rated payload, kg (None: not known, the gate's
            ``rated_mass_kg`` must be set).
        home: the configuration the paths move around, rad.
        task: the new task path's first and last configurations, rad.
        default_end_effector: what the flange carries when ``[arm] end_effector`` is unset.
        digest: SHA-256 (hex, 16 digits) of ``text`` and the flange: the identity files record.
    """

    name: str
    source: str
    text: str
    full_text: str
    flange: str
    joint_names: tuple[str, ...]
    link_bodies: tuple[str, ...]
    limits: Limits
    rated_payload_kg: float | None
    home: np.ndarray
    task: tuple[np.ndarray, np.ndarray]
    default_end_effector: str
    own_end_effector: str | None = None
    """The end effector ``full_text`` carries beyond the flange (the Panda's Franka Hand)."""
    locked: tuple[str, ...] = field(default=())
    """Movable joints beyond the flange, locked at zero in ``full_text``'s model."""

    @property
    def source_spec(self) -> str:
        """What names it in ``[arm] model``: a named arm model's name, else its path."""
        return self.name if self.name in BUILTINS and self.source == str(
            builtin_file(self.name)) else self.source

    @property
    def digest(self) -> str:
        return hashlib.sha256(f"{self.text}\nflange={self.flange}".encode()).hexdigest()[:16]

    def record(self) -> dict:
        """What arm files and model files record of it."""
        return {"name": self.name, "digest": self.digest}

    def end_effector_spec(self, end_effector: str | None) -> str:
        """The end effector ``end_effector`` declares on this arm model: itself, or None and
        "" its default (:attr:`default_end_effector`)."""
        return str(end_effector or self.default_end_effector)

    def carries_own(self, end_effector: str | None) -> bool:
        """Whether the end effector ``end_effector`` (a spec; None: the default) is the one
        this description's own file carries beyond the flange (the Panda's Franka Hand)."""
        return self.end_effector_spec(end_effector) == self.own_end_effector

    def __repr__(self) -> str:
        return f"ArmDescription({self.name!r}, {self.digest})"


def default_home(q_min: np.ndarray, q_max: np.ndarray) -> np.ndarray:
    """The middle of each joint's range, joints 2, 4 and 6 bent by a third of their half
    range (an arm stretched straight up feels no gravity in its wrist)."""
    mid = 0.5 * (q_min + q_max)
    half = 0.5 * (q_max - q_min)
    bend = np.array([0.0, 1.0, 0.0, 1.0, 0.0, 1.0, 0.0]) * half / 3.0
    return mid + bend


TASK_FRACTIONS = (np.array([-0.34, 0.28, 0.17, 0.40, 0.17, -0.21, -0.28]),
                  np.array([0.41, 0.40, -0.21, 0.53, 0.24, 0.32, -0.45]))
"""The new task path's ends on an arm model given by a file: ``home`` plus these fractions
of each joint's half range (the Panda's task path, as fractions of its own ranges)."""


def default_task(home: np.ndarray, q_min: np.ndarray, q_max: np.ndarray):
    """The new task path's ends of an arm model given by a file (:data:`TASK_FRACTIONS`),
    kept 5 % of the range inside the limits."""
    half = 0.5 * (q_max - q_min)
    margin = 0.05 * (q_max - q_min)
    return tuple(np.clip(home + f * half, q_min + margin, q_max - margin)
                 for f in TASK_FRACTIONS)


# -- finding the files ---------------------------------------------------------------------
def _site_roots() -> list[FsPath]:
    return [FsPath(r) for r in (*site.getsitepackages(), site.getusersitepackages(), *sys.path)]


@cache
def builtin_file(name: str) -> FsPath:
    """The file of the named arm model."""
    if name == "panda":
        for root in _site_roots():
            cand = root / "cmeel.prefix/share/example-robot-data/robots/panda_description/urdf"
            if (cand / "panda.urdf").is_file():
                return cand / "panda.urdf"
        raise FileNotFoundError("example-robot-data's panda.urdf not found under any "
                                "site-packages; install the package example-robot-data")
    spec = find_spec("franky_sim")  # located: its server runs in deploy.simcell.FciSim only
    for folder in (spec.submodule_search_locations or []) if spec else []:
        cand = FsPath(folder) / "assets" / "fr3_clean.urdf"
        if cand.is_file():
            return cand
    raise FileNotFoundError("franky-sim's fr3_clean.urdf (franka_description's FR3) not "
                            "found; install the package franky-sim")


def _limits_of(arm, source: str, builtin: BuiltinArm | None) -> Limits:
    def column(key, default=None):
        vals = [joint_limit(j, key, source) for j in arm]
        if any(v is None for v in vals):
            if default is not None:
                return np.array(default, dtype=float)
            missing = [j.get("name") for j, v in zip(arm, vals, strict=True) if v is None]
            raise arm_error(source, f"joints {', '.join(missing)} give no <limit {key}=...>; the "
                         "paths and checks need every arm joint's limits")
        return np.array(vals, dtype=float)

    q_min, q_max = (np.array(builtin.q_limits[0]), np.array(builtin.q_limits[1])) \
        if builtin and builtin.q_limits else (column("lower"), column("upper"))
    dq = np.array(builtin.dq_max) if builtin and builtin.dq_max else column("velocity")
    tau = column("effort")
    if np.any(q_max <= q_min) or np.any(dq <= 0.0) or np.any(tau <= 0.0):
        raise arm_error(source, f"joint limits must have lower < upper and velocity, effort > 0; "
                     f"got lower {q_min}, upper {q_max}, velocity {dq}, effort {tau}")
    # acceleration: the datasheet's for a named arm; else five times the velocity limit a
    # second (URDF has no acceleration limit)
    ddq = np.array(builtin.ddq_max) if builtin else 5.0 * dq
    out = Limits(q_min, q_max, dq, ddq, tau)
    for a in (out.q_min, out.q_max, out.dq_max, out.ddq_max, out.tau_max):
        a.flags.writeable = False
    return out


_READ: dict[str, ArmDescription] = {}
"""The descriptions this process has read, by digest (:func:`described_by`)."""


def described_by(record: dict | None) -> ArmDescription:
    """The description a file's record ``{"name", "digest"}`` names (None: the default arm
    model): a named arm model, or a description this process has read (the configured one).

    Raises:
        iem.errors.InvalidInputError: a description file this process was not given.
    """
    if not record:
        return arm_description(None)
    name, digest = str(record.get("name")), str(record.get("digest"))
    if digest in _READ:
        return _READ[digest]
    if name in BUILTINS and arm_description(name).digest == digest:
        return arm_description(name)
    raise InvalidInputError(f"the file is for the arm model {name!r} (digest {digest}), which "
                            f"this process was not given; give it with [arm] model "
                            f"(--arm-model PATH)" + (f"; the installed {name!r} has digest "
                                                     f"{arm_description(name).digest}"
                                                     if name in BUILTINS else ""))


def described(description) -> ArmDescription:
    """``description`` as an :class:`ArmDescription`: itself, or the arm model it names (a
    name or a path; None: the default)."""
    return description if isinstance(description, ArmDescription) else \
        arm_description(description)


def arm_description(spec: str | None = None, flange: str | None = None) -> ArmDescription:
    """:func:`read_description`, once per ``(spec, flange)``; remembered by digest for
    :func:`described_by`."""
    out = read_description(str(spec or DEFAULT_ARM_MODEL), flange or None)
    _READ.setdefault(out.digest, out)
    return out


@cache
def read_description(spec: str | None = None, flange: str | None = None) -> ArmDescription:
    """The arm model ``spec`` ("panda", "fr3" or a URDF path; None: "panda"), its
    flange ``flange`` (None: the named arm's, or the file's own, :func:`_auto_flange`).

    Raises:
        iem.errors.InvalidInputError: an unreadable file, no flange, not a serial chain of
            seven revolute joints, a moving body without an inertial, missing limits.
    """
    spec = str(spec or DEFAULT_ARM_MODEL)
    builtin = BUILTINS.get(spec)
    if builtin is not None:
        path = builtin_file(spec)
        flange = flange or builtin.flange
        name = spec
    else:
        path = FsPath(spec)
        name = path.name
        if path.suffix.lower() not in (".urdf", ".xml"):
            raise InvalidInputError(f"arm model {spec!r} is not valid: give "
                                    f"{', '.join(map(repr, BUILTIN))}, or the path of a "
                                    ".urdf file")
    try:  # a regular file, within bounds
        text = read_text(path, MAX_URDF_BYTES, "URDF file", InvalidInputError)
    except InvalidInputError as exc:  # "PATH: ...", as arm_error's messages read
        raise InvalidInputError(f"arm model {exc}") from exc
    if parse(text, str(path)).tag == "mujoco":
        raise arm_error(str(path), "an MJCF file: the plug-in reads an arm's description from "
                        "a URDF only; give the arm's URDF")
    _, text, full_text, flange, arm, bodies, locked = read_urdf(
        text, str(path), flange, builtin.prefix if builtin else "")
    limits = _limits_of(arm, str(path), builtin)
    home = np.array(builtin.home, dtype=float) if builtin and builtin.home else \
        default_home(limits.q_min, limits.q_max)
    home.flags.writeable = False
    task = tuple(np.array(t, dtype=float) for t in builtin.task) if builtin and builtin.task \
        else default_task(home, limits.q_min, limits.q_max)
    for a in task:
        a.flags.writeable = False
    return ArmDescription(
        name=name, source=str(path), text=text,
        full_text=full_text if builtin and builtin.own_end_effector else text,
        flange=flange, joint_names=tuple(j.get("name") for j in arm), link_bodies=bodies,
        limits=limits, rated_payload_kg=builtin.rated_payload_kg if builtin else None,
        home=home, task=task,
        default_end_effector=builtin.default_end_effector if builtin else "none",
        own_end_effector=builtin.own_end_effector if builtin else None,
        locked=locked if builtin and builtin.own_end_effector else ())
