"""The end effector: what is mounted on the flange as part of the arm, not the payload.

An arm may carry the Franka Hand, another tool, or nothing: what it carries is the arm's, and
what the plug-in identifies is the payload beyond it. A wrong end effector reads as a payload:
a bare arm through the hand's model reads about -0.7 kg.

An end effector is declared (``[arm] end_effector`` in ``cell.toml``, ``--end-effector`` on
the commands that take ``--arm``) as one of:

- ``"franka_hand"``: the Franka Hand and its fingers (0.73 kg and two 15 g fingers), as
  example-robot-data's Panda description has them, mounted on any arm's flange (the default
  on the Panda and the FR3);
- ``"none"``: a bare flange (the default on an arm model given by a file);
- a path to a payload-style TOML file (:mod:`sim.payload`: mass, CoM in the flange frame,
  inertia about the CoM) of the tool that is part of the arm;
- a path to Franka Desk's end-effector file, ``endeffector-config.json``
  (:mod:`sim.desk_file`: its ``mass``, ``centerOfMass`` and ``inertia``; a mass of 0 is a
  bare flange).

Body 7 of the arm model is then the arm's bodies from joint 7 to the flange plus the end
effector (:meth:`EndEffector.body7`). :class:`EndEffector` holds one, as an inertia in the
flange frame, with a label that arm files and model files record, so that a model or an arm
made for one end effector is refused with another.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass
from functools import cache
from pathlib import Path as FsPath

import numpy as np
import pinocchio as pin

from iem.errors import InvalidInputError
from iem.payload import Payload

DEFAULT_END_EFFECTOR = "franka_hand"
"""The end effector of the nominal model and of files that record none."""
NAMED = ("franka_hand", "none")
"""End effectors known by name; anything else must be a payload TOML file."""


@dataclass(frozen=True, eq=False)
class EndEffector:
    """One end effector.

    Attributes:
        spec: as declared: ``"franka_hand"``, ``"none"`` or the tool file's path.
        label: what files record: the name, or ``"<file stem>:<CRC32 of its parameters>"``.
        inertia: the body as a ``pin.Inertia`` in the flange frame (None: nothing).
    """

    spec: str
    label: str
    inertia: pin.Inertia | None

    @property
    def mass(self) -> float:
        """Its mass, kg."""
        return 0.0 if self.inertia is None else float(self.inertia.mass)

    def params(self, description=None) -> np.ndarray:
        """``(10,)`` Pinocchio dynamic parameters it adds to body 7 of the arm ``description``
        (None: the default arm model), in the joint-7 frame."""
        from .description import described
        from .nominal import flange_placement

        desc = described(description)
        if self.inertia is None:
            return np.zeros(10)
        if desc.carries_own(self.spec):
            return _own_hand(desc)  # the file's own, exactly as the file gives it
        return flange_placement(desc).act(self.inertia).toDynamicParameters()

    def with_payload(self, payload, name: str = "end effector") -> Payload:
        """This end effector and ``payload`` (a :class:`iem.payload.Payload` on the flange;
        None: none) as one body: mass, CoM in the flange frame, inertia about that CoM (what
        Desk's end-effector settings take for a tool with something added to it)."""
        total = pin.Inertia.Zero() if self.inertia is None else self.inertia.copy()
        if payload is not None:
            total += pin.Inertia(payload.mass, np.asarray(payload.com), payload.inertia_matrix)
        if not total.mass > 0.0:
            raise InvalidInputError("an end effector and payload of no mass make no body")
        i = total.inertia
        return Payload(name=name, mass=float(total.mass), com=tuple(total.lever.tolist()),
                       inertia=(i[0, 0], i[0, 1], i[0, 2], i[1, 1], i[1, 2], i[2, 2]))

    def body7(self, description=None) -> np.ndarray:
        """``(10,)`` parameters of body 7 carrying it: the arm's bodies from joint 7 to the
        flange plus the end effector."""
        from .nominal import link7_params

        return link7_params(description) + self.params(description)


@cache
def _own_hand(description) -> np.ndarray:
    """The hand a description's own file fuses into body 7 (joint-7 frame)."""
    from .nominal import link7_params, nominal_model

    return nominal_model(description).inertias[7].toDynamicParameters() - \
        link7_params(description)


@cache
def _franka_hand() -> pin.Inertia:
    """The Franka Hand with its fingers, in the flange frame: example-robot-data's Panda
    hand, taken off that description's flange."""
    from .description import arm_description
    from .nominal import flange_placement

    panda = arm_description("panda")
    return flange_placement(panda).actInv(
        pin.Inertia.FromDynamicParameters(_own_hand(panda)))


def end_effector(spec: str | None) -> EndEffector:
    """The end effector declared as ``spec`` (None or "": the default, the Franka Hand).

    Raises:
        iem.errors.InvalidInputError: neither a known name nor a readable payload file.
    """
    spec = str(spec or DEFAULT_END_EFFECTOR)
    if spec == "franka_hand":
        return EndEffector(spec, spec, _franka_hand())
    if spec == "none":
        return EndEffector(spec, spec, None)
    path = FsPath(spec)
    if path.suffix not in (".toml", ".json"):
        raise InvalidInputError(f"end effector {spec!r} is not valid: give 'franka_hand', "
                                f"'none', the path of a payload-style .toml file of the "
                                f"tool mounted on the flange, or Franka Desk's "
                                f"endeffector-config.json (.json)")
    if path.suffix == ".json":  # Desk's file: mass, centerOfMass, transformation, inertia
        from .desk_file import read_desk_file

        tool = read_desk_file(path).payload
        if tool is None:  # a massless end effector: a bare flange by another name
            return EndEffector(str(path), f"{path.stem}:none", None)
    else:
        from .payload import load_payload

        tool = load_payload(path)
    inertia = pin.Inertia(tool.mass, np.asarray(tool.com), tool.inertia_matrix)
    crc = zlib.crc32(np.round(tool.to_phi(), 12).tobytes())
    return EndEffector(str(path), f"{path.stem}:{crc:08x}", inertia)


def end_effector_of(declared=None, description=None) -> EndEffector:
    """The end effector on the arm model ``description`` (None: the default arm model) that
    ``declared`` names: an :class:`EndEffector` as it is, else :func:`end_effector` of the
    spec, None and "" meaning the arm model's default
    (:meth:`~sim.description.ArmDescription.end_effector_spec`: the Franka Hand on panda and
    fr3, none on a URDF file).

    Raises:
        iem.errors.InvalidInputError: as :func:`end_effector`."""
    from .description import described

    if isinstance(declared, EndEffector):
        return declared
    return end_effector(described(description).end_effector_spec(declared))


def label_of(record_value) -> str:
    """The end-effector label a file records (files that record none: the default)."""
    return str(record_value) if record_value else DEFAULT_END_EFFECTOR


def check_same(have: str, want: str, have_what: str, want_what: str) -> None:
    """Refuse unless the end-effector labels ``have`` and ``want`` agree, naming both."""
    if label_of(have) != label_of(want):
        raise InvalidInputError(
            f"end effector mismatch: {have_what} is for {label_of(have)!r}, {want_what} "
            f"declares {label_of(want)!r}; declare the end effector the arm carries "
            f"([arm] end_effector in cell.toml, --end-effector) and calibrate or train "
            f"for it ('iem calibrate --end-effector', 'iem train --end-effector')")
