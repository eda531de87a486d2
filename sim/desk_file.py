"""Franka Desk's end-effector file, ``endeffector-config.json``: read and write.

Desk (the FR3's web interface) takes a custom end effector as an archive whose
``endeffector-config.json`` holds (Franka's "End effector commissioning" documentation):

- ``id`` (string: no spaces, not beginning with ``ee-``), ``name``, ``color`` (strings,
  for Desk's display);
- ``mass`` (kg);
- ``centerOfMass``: the CoM, 3 values, m, in the flange frame F (libfranka reports the
  configured end effector as ``m_ee``, ``F_x_Cee``: "with respect to flange frame");
- ``transformation``: 16 values, the end-effector (TCP) frame in the flange frame, a 4x4
  homogeneous transform stored column by column (column-major: the translation is values
  12, 13, 14; values 3, 7, 11 are 0 and 15 is 1), as libfranka's ``F_T_NE``;
- ``inertia``: 9 values, the 3x3 inertia tensor about the CoM (libfranka's ``I_ee``: "with
  respect to center of mass"), column by column (it is symmetric), kg·m².

:func:`read_desk_file` checks each field and names the one that is wrong: a file that is not
JSON, a missing or non-numeric field, a wrong count, a transformation that is not a rigid
transform, an inertia that is not symmetric or not physical (positive, with the triangle
inequality of its principal moments: :meth:`iem.payload.Payload.consistency_violations`).
Other keys are left alone (Desk's archives may carry more). :func:`desk_document` makes the
document :func:`write_desk_file` writes.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path as FsPath

import numpy as np

from iem.errors import PayloadError
from iem.payload import Payload, set_load_values

MECHANICAL = ("mass", "centerOfMass", "transformation", "inertia")
"""The fields the plug-in needs, in Desk's names."""
DISPLAY = ("id", "name", "color")
"""Desk's display fields (strings)."""
IDENTITY = (1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0)
"""The identity transformation, column-major."""
_C = 0.5 ** 0.5
FRANKA_HAND_TRANSFORMATION = (_C, -_C, 0.0, 0.0, _C, _C, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0,
                              0.0, 0.0, 0.1034, 1.0)
"""The Franka Hand's end-effector frame in the flange frame, column-major: 0.1034 m along z,
turned -45° about z (libfranka's ``F_T_NE`` with the hand; franky-sim's
``RobotParameters.ee_tcp_xyz`` and ``ee_tcp_rpy``)."""
ROTATION_TOL = 1e-4
"""How far a transformation's rotation may be from orthonormal (rounded values in a file)."""
SYMMETRY_TOL = 1e-9
"""How far the inertia's mirrored entries may differ, kg·m²."""
MAX_MASS_KG = 50.0


@dataclass(frozen=True)
class DeskEndEffector:
    """One Desk end effector: its body (:attr:`payload`: mass, CoM in the flange frame,
    inertia about the CoM) and what else the file says (``transformation`` column-major,
    ``id``, ``name``, ``color``; ``extra``: the file's other keys, kept for writing)."""

    payload: Payload | None
    transformation: tuple[float, ...]
    id: str | None
    name: str | None
    color: str | None
    extra: dict


def _numbers(doc: dict, key: str, n: int | None, where: str) -> list[float]:
    value = doc[key]
    want = "a number" if n is None else f"a list of {n} numbers"
    values = [value] if n is None else value
    if n is not None and (not isinstance(value, list) or len(value) != n):
        got = f"{len(value)} values" if isinstance(value, list) else repr(value)
        raise PayloadError(f"{where}: field {key!r} must be {want}, got {got}")
    out = []
    for i, v in enumerate(values):
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            at = "" if n is None else f"[{i}]"
            raise PayloadError(f"{where}: field {key!r}{at} must be a finite number, got {v!r}")
        out.append(float(v))
    return out


def desk_from_dict(doc, where: str = "endeffector-config.json") -> DeskEndEffector:
    """Check a parsed ``endeffector-config.json`` (see the module docstring)."""
    if not isinstance(doc, dict):
        raise PayloadError(f"{where}: must be a JSON object with the fields "
                           f"{', '.join(MECHANICAL)}, got {type(doc).__name__}")
    missing = [k for k in MECHANICAL if k not in doc]
    if missing:
        raise PayloadError(f"{where}: missing field(s) {missing}; Desk's end-effector file "
                           f"holds {list(MECHANICAL)} (and {list(DISPLAY)})")
    text = {}
    for key in DISPLAY:
        value = doc.get(key)
        if value is not None and not isinstance(value, str):
            raise PayloadError(f"{where}: field {key!r} must be a string, got {value!r}")
        text[key] = value
    if text["id"] is not None and (not text["id"] or text["id"].startswith("ee-")
                                   or any(c.isspace() for c in text["id"])):
        raise PayloadError(f"{where}: field 'id' = {text['id']!r} is not valid: Desk wants a "
                           "non-empty identifier without spaces, not beginning with 'ee-'")
    (mass,) = _numbers(doc, "mass", None, where)
    if not 0.0 <= mass <= MAX_MASS_KG:
        raise PayloadError(f"{where}: field 'mass' = {mass!r} is out of range; valid is 0 to "
                           f"{MAX_MASS_KG:g} kg")
    com = _numbers(doc, "centerOfMass", 3, where)
    transform = _numbers(doc, "transformation", 16, where)
    _check_transform(transform, where)
    flat = _numbers(doc, "inertia", 9, where)
    tensor = np.reshape(flat, (3, 3), order="F")
    if not np.allclose(tensor, tensor.T, rtol=0.0, atol=SYMMETRY_TOL):
        raise PayloadError(f"{where}: field 'inertia' is not symmetric ({flat}); Desk wants "
                           "the 3x3 tensor about the CoM, 9 values column by column")
    payload = None
    if mass > 0.0:
        payload = Payload.from_set_load(mass, com, flat, name=text["name"] or text["id"]
                                        or FsPath(where).stem)
        problems = payload.consistency_violations()
        if problems:
            raise PayloadError(f"{where}: field 'inertia' is not physical: "
                               + "; ".join(problems))
    elif np.any(tensor) or any(com):
        raise PayloadError(f"{where}: field 'mass' is 0 but 'centerOfMass' or 'inertia' is "
                           "not: a massless body has neither")
    extra = {k: v for k, v in doc.items() if k not in MECHANICAL and k not in DISPLAY}
    return DeskEndEffector(payload, tuple(transform), text["id"], text["name"], text["color"],
                           extra)


def _check_transform(values: list[float], where: str) -> None:
    m = np.reshape(values, (4, 4), order="F")
    if not np.allclose(m[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9):
        raise PayloadError(f"{where}: field 'transformation' is not a homogeneous transform "
                           f"stored column by column: values 3, 7, 11, 15 must be 0, 0, 0, 1, "
                           f"got {[values[3], values[7], values[11], values[15]]} (a row-major "
                           "matrix puts the translation there)")
    r = m[:3, :3]
    if not (np.allclose(r.T @ r, np.eye(3), atol=ROTATION_TOL)
            and np.linalg.det(r) > 0.0):
        raise PayloadError(f"{where}: field 'transformation' has no rotation in its upper-left "
                           f"3x3 (orthonormal, determinant +1): {np.round(r, 6).tolist()}")


def read_desk_file(path) -> DeskEndEffector:
    """Read and check ``endeffector-config.json`` at ``path``; PayloadError naming the field
    that is wrong."""
    path = FsPath(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise PayloadError(f"{path}: cannot read the end-effector file: "
                           f"{exc.strerror or exc}") from exc
    except UnicodeDecodeError as exc:
        raise PayloadError(f"{path}: not UTF-8 text: {exc}") from exc
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise PayloadError(f"{path}: not valid JSON: {exc}") from exc
    return desk_from_dict(doc, str(path))


def desk_document(payload: Payload | None, *, base: DeskEndEffector | None = None,
                  id: str | None = None, name: str | None = None) -> dict:
    """The ``endeffector-config.json`` of the body ``payload`` (None: massless): the
    transformation, display fields and other keys of ``base`` (a Desk file read) when given,
    else the identity transformation; ``id`` and ``name`` replace the base's."""
    mass, com, inertia = set_load_values(payload)
    doc = dict(base.extra) if base is not None else {}
    for key, value in (("id", id or (base and base.id)), ("name", name or (base and base.name)),
                       ("color", base and base.color)):
        if value:
            doc[key] = value
    doc.update({"mass": float(mass), "centerOfMass": [float(v) for v in com],
                "transformation": list(base.transformation if base is not None else IDENTITY),
                "inertia": [float(v) for v in inertia]})
    desk_from_dict(doc, "the end-effector file written")  # what is written reads back
    return doc


def base_of(end_effector_spec: str) -> DeskEndEffector | None:
    """What a Desk file written for the end effector ``end_effector_spec`` takes from it
    besides the body: a Desk file's own fields; the Franka Hand's frame
    (:data:`FRANKA_HAND_TRANSFORMATION`); None (the identity) for anything else."""
    if end_effector_spec.endswith(".json"):
        return read_desk_file(end_effector_spec)
    if end_effector_spec == "franka_hand":
        return DeskEndEffector(None, FRANKA_HAND_TRANSFORMATION, None, None, None, {})
    return None


def write_desk_file(path, document: dict) -> None:
    """Write ``document`` (:func:`desk_document`) as JSON."""
    FsPath(path).write_text(json.dumps(document, indent=2) + "\n", encoding="utf-8")
