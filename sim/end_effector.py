"""The end effector: what is mounted on the flange as part of the arm, not the payload.

The nominal Panda model (example-robot-data's URDF, :mod:`sim.robot`) fuses the Franka Hand
(0.73 kg and two 15 g fingers) into the body of joint 7. An arm may carry the hand, another
tool, or nothing: what it carries is the arm's, and what the plug-in identifies is the payload
beyond it. A wrong end effector reads as a payload: a bare arm through the hand's model reads
about -0.7 kg.

An end effector is declared (``[arm] end_effector`` in ``cell.toml``, ``--end-effector`` on
the commands that take ``--arm``) as one of:

- ``"franka_hand"`` (the default): the URDF's hand and fingers, as the nominal model has them;
- ``"none"``: a bare flange: body 7 is ``panda_link7`` of the URDF alone;
- a path to a payload-style TOML file (:mod:`sim.payload`: mass, CoM in the flange frame,
  inertia about the CoM) of the tool that is part of the arm: body 7 is ``panda_link7`` plus
  that tool.

:class:`EndEffector` holds one, with the ten Pinocchio dynamic parameters it adds to body 7
(in the joint-7 frame) and a label that arm files and model files record, so that a model or
an arm made for one end effector is refused with another.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
import zlib
from dataclasses import dataclass
from functools import cache
from pathlib import Path as FsPath

import numpy as np
import pinocchio as pin

from iem.errors import InvalidInputError

DEFAULT_END_EFFECTOR = "franka_hand"
"""The end effector of the nominal model and of files that record none."""
NAMED = ("franka_hand", "none")
"""End effectors known by name; anything else must be a payload TOML file."""


@cache
def link7_params() -> np.ndarray:
    """``(10,)`` Pinocchio dynamic parameters of ``panda_link7`` alone (the URDF's inertial,
    joint-7 frame): body 7 without any end effector."""
    from .robot import panda_urdf

    root = ET.parse(panda_urdf()).getroot()
    link = next(e for e in root.findall("link") if e.get("name") == "panda_link7")
    inertial = link.find("inertial")
    xyz = np.array([float(v) for v in inertial.find("origin").get("xyz").split()])
    mass = float(inertial.find("mass").get("value"))
    a = inertial.find("inertia").attrib
    ixx, ixy, ixz, iyy, iyz, izz = (float(a[k]) for k in
                                    ("ixx", "ixy", "ixz", "iyy", "iyz", "izz"))
    inertia = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    out = pin.Inertia(mass, xyz, inertia).toDynamicParameters()
    out.flags.writeable = False
    return out


@dataclass(frozen=True, eq=False)
class EndEffector:
    """One end effector.

    Attributes:
        spec: as declared: ``"franka_hand"``, ``"none"`` or the tool file's path.
        label: what files record: the name, or ``"<file stem>:<CRC32 of its parameters>"``.
        params: ``(10,)`` Pinocchio dynamic parameters it adds to body 7, joint-7 frame
            (kg, kg·m, kg·m² about the joint origin).
    """

    spec: str
    label: str
    params: np.ndarray

    @property
    def mass(self) -> float:
        """Its mass, kg."""
        return float(self.params[0])

    def body7(self) -> np.ndarray:
        """``(10,)`` parameters of body 7 carrying it: ``panda_link7`` plus the tool."""
        return link7_params() + self.params


def _hand_params() -> np.ndarray:
    from .robot import nominal_link_params

    return nominal_link_params()[6] - link7_params()


def end_effector(spec: str | None) -> EndEffector:
    """The end effector declared as ``spec`` (None or "": the default, the Franka Hand).

    Raises:
        iem.errors.InvalidInputError: neither a known name nor a readable payload file.
    """
    spec = str(spec or DEFAULT_END_EFFECTOR)
    if spec == "franka_hand":
        return EndEffector(spec, spec, _hand_params())
    if spec == "none":
        return EndEffector(spec, spec, np.zeros(10))
    path = FsPath(spec)
    if path.suffix != ".toml":
        raise InvalidInputError(f"end effector {spec!r} is not valid: give 'franka_hand', "
                                f"'none', or the path of a payload-style .toml file of the "
                                f"tool mounted on the flange")
    from .payload import load_payload
    from .robot import flange_placement

    tool = load_payload(path)
    inertia = flange_placement().act(
        pin.Inertia(tool.mass, np.asarray(tool.com), tool.inertia_matrix))
    params = inertia.toDynamicParameters()
    crc = zlib.crc32(np.round(tool.to_phi(), 12).tobytes())
    return EndEffector(str(path), f"{path.stem}:{crc:08x}", params)


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
