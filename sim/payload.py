"""The payload file format (TOML) of the value type :class:`iem.payload.Payload`.

Conventions (libfranka's ``setLoad``):

- ``com``: centre of mass in the flange frame (Franka's F, i.e. ``panda_link8``), in m.
- ``inertia``: inertia tensor about the centre of mass, in flange axes, in kg·m².
- ``phi``: the paper's parameter vector ``[m, m*rx, m*ry, m*rz, Ixx, Ixy, Ixz, Iyy, Iyz, Izz]``
  with the inertia taken about the *flange origin* (parallel-axis shift of ``inertia``).

Payload files are TOML::

    name = "box-3-weights"
    mass = 1.615                      # kg, 0 < mass <= 10
    com = [0.01, -0.02, 0.06]         # m, flange frame, each |x| <= 1
    inertia = [Ixx, Ixy, Ixz, Iyy, Iyz, Izz]   # kg·m² about the CoM, flange axes
    phi_std = [...]                   # optional: standard deviations of phi (10 values)

``phi_std`` (optional; ``iem identify`` writes it) gives how well each parameter of ``phi``
is known, in phi's order and units (kg, kg·m, kg·m² about the flange origin); the plug-in
uses it as the prior's spread when it starts from the file (``[estimate] initial_payload``).
"""

from __future__ import annotations

import math
from difflib import get_close_matches
from pathlib import Path as FsPath

import numpy as np

from iem.errors import PayloadError
from iem.payload import Payload
from iem.user_files import read_toml

MAX_FILE_MASS = 10.0
"""Largest mass a payload file may declare, in kg (far above the Panda's 3 kg rating)."""
MAX_FILE_COM = 1.0
"""Largest |component| of a CoM a payload file may declare, in m."""
MAX_FILE_INERTIA = 10.0
"""Largest |component| of an inertia a payload file may declare, in kg·m²."""

def _number(doc: dict, key: str, where: str, lo: float, hi: float) -> float:
    value = doc[key]
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise PayloadError(f"{where}: key {key!r} must be a number in [{lo:g}, {hi:g}], "
                           f"got {value!r}")
    if not lo <= value <= hi:
        raise PayloadError(f"{where}: key {key!r} = {value!r} is out of range; "
                           f"valid is [{lo:g}, {hi:g}]")
    return float(value)


def _numbers(doc: dict, key: str, where: str, n: int, bound: float, names: str) -> list[float]:
    value = doc[key]
    if not isinstance(value, list) or len(value) != n:
        raise PayloadError(f"{where}: key {key!r} must be a list of {n} numbers {names}, "
                           f"got {value!r}")
    out = []
    for i, v in enumerate(value):
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise PayloadError(f"{where}: key {key!r}[{i}] must be a finite number, got {v!r}")
        if abs(v) > bound:
            raise PayloadError(f"{where}: key {key!r}[{i}] = {v!r} is out of range; "
                               f"valid is [{-bound:g}, {bound:g}]")
        out.append(float(v))
    return out


OPTIONAL_KEYS = ("phi_std",)
"""Keys a payload file may hold besides the required ones."""


def payload_from_dict(doc: dict, where: str = "payload") -> Payload:
    """Build and check a payload from a parsed TOML table (see the module docstring)."""
    required = ("name", "mass", "com", "inertia")
    valid = [*required, *OPTIONAL_KEYS]
    unknown = sorted(set(doc) - set(valid))
    if unknown:  # first: a misspelt key is also a missing one, and its name says which
        guesses = [f"{k!r} (did you mean {close[0]!r}?)" if (close := get_close_matches(
            k, valid, n=1)) else repr(k) for k in unknown]
        raise PayloadError(f"{where}: unknown key(s) {', '.join(guesses)}; valid keys are "
                           f"{valid}")
    missing = [k for k in required if k not in doc]
    if missing:
        raise PayloadError(f"{where}: missing key(s) {missing}; a payload needs {list(required)}")
    if not isinstance(doc["name"], str) or not doc["name"].strip():
        raise PayloadError(f"{where}: key 'name' must be a non-empty string, got {doc['name']!r}")
    mass = _number(doc, "mass", where, 0.0, MAX_FILE_MASS)
    if mass <= 0.0:
        raise PayloadError(f"{where}: key 'mass' must be > 0 kg; valid is (0, {MAX_FILE_MASS:g}]")
    com = _numbers(doc, "com", where, 3, MAX_FILE_COM, "[x, y, z] in m")
    inertia = _numbers(doc, "inertia", where, 6, MAX_FILE_INERTIA,
                       "[Ixx, Ixy, Ixz, Iyy, Iyz, Izz] in kg·m² about the CoM")
    payload = Payload(name=doc["name"], mass=mass, com=tuple(com), inertia=tuple(inertia))
    problems = payload.consistency_violations()
    if problems:
        raise PayloadError(f"{where}: key 'inertia' is not physically consistent: "
                           + "; ".join(problems))
    return payload


def phi_std_from_dict(doc: dict, where: str = "payload") -> np.ndarray | None:
    """The optional ``phi_std`` of a parsed payload file (10 values > 0), or None."""
    if "phi_std" not in doc:
        return None
    values = _numbers(doc, "phi_std", where, 10, MAX_FILE_MASS,
                      "standard deviations of [m, m·rx, m·ry, m·rz, Ixx, Ixy, Ixz, Iyy, Iyz, "
                      "Izz] (kg, kg·m, kg·m²)")
    if not all(v > 0.0 for v in values):
        raise PayloadError(f"{where}: key 'phi_std' must hold 10 values > 0, got {values}")
    return np.array(values)


def load_payload_prior(path) -> tuple[Payload, np.ndarray | None]:
    """A payload file and its optional ``phi_std`` (None if the file has none)."""
    doc = _read_toml(path)
    return payload_from_dict(doc, where=str(path)), phi_std_from_dict(doc, where=str(path))


def load_payload(path) -> Payload:
    """Read a payload TOML file; errors name the file, the key and the valid range."""
    doc = _read_toml(path)
    payload = payload_from_dict(doc, where=str(path))
    phi_std_from_dict(doc, where=str(path))  # checked even when not used
    return payload


def _read_toml(path) -> dict:
    """The TOML of a payload file, read as ``cell.toml`` is (:func:`iem.user_files.read_toml`:
    a regular file, within bounds)."""
    return read_toml(FsPath(path), "payload file", PayloadError)


def payload_to_toml(payload: Payload, phi_std=None) -> str:
    """The TOML text of a payload file (round-trips through :func:`load_payload`), with its
    ``phi_std`` if given."""
    def fmt(values):
        return "[" + ", ".join(repr(float(v)) for v in values) + "]"

    name = payload.name.replace("\\", "\\\\").replace('"', '\\"')
    return (
        f'name = "{name}"\n'
        f"mass = {float(payload.mass)!r}  # kg\n"
        f"com = {fmt(payload.com)}  # m, flange frame\n"
        f"inertia = {fmt(payload.inertia)}  # kg·m² about the CoM: Ixx, Ixy, Ixz, Iyy, Iyz, Izz\n"
        + ("" if phi_std is None else
           f"phi_std = {fmt(phi_std)}  # std of [m, m·r, I about the flange origin]\n")
    )


def save_payload(payload: Payload, path) -> None:
    """Write a payload TOML file."""
    FsPath(path).write_text(payload_to_toml(payload), encoding="utf-8")
