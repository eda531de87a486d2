"""What a link's load command can carry: each value's range and step, one check for every link.

A load travels as ten values: the mass (kg), the CoM in the flange frame (m) and the inertia
about the CoM (kg·m², ``Ixx Ixy Ixz Iyy Iyz Izz``). Each link kind declares the range of its
wire in the one table of link kinds (:attr:`firmware_bridge.links.LinkKind.load_range`; the
range itself: :meth:`firmware_bridge.links.LinkKind.wire_range`):

- ``"dbc"``: the CAN links (and a replayed CAN log): the DBC's signals of the profile's load
  command, each an integer of so many bits times a scale (:func:`of_profile`); a mass that
  rounds to 0 on the wire would mean "no load" and cannot be carried;
- ``"float64"``: the serial link's msgpack floats, libfranka's doubles and franka_ros2's
  float64 fields (:data:`FLOAT64`): any finite number, a mass not below 0.

:meth:`LoadRange.error` checks a load against either, the same way; the safety gate asks it
before a load is let through, so a load the wire cannot carry is refused there (reason
``out_of_wire_range``) instead of failing in ``send``. What a body can physically be is the
gate's own check, on every link alike.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

NAMES = ("Mass", "ComX", "ComY", "ComZ", "Ixx", "Ixy", "Ixz", "Iyy", "Iyz", "Izz")
"""The ten values of a load, in the order :func:`values` gives them (the DBC's signal
names)."""
UNITS = ("kg", "m", "m", "m", "kg.m2", "kg.m2", "kg.m2", "kg.m2", "kg.m2", "kg.m2")
RANGES = ("dbc", "float64")
"""The kinds of wire range a link kind may declare."""


@dataclass(frozen=True)
class Field:
    """One value's range: ``[lo, hi]`` in steps of ``step`` (None: any float between)."""

    name: str
    lo: float
    hi: float
    unit: str
    step: float | None = None

    def error(self, value: float) -> str | None:
        """Why ``value`` does not fit, or None."""
        value = float(value)
        if math.isfinite(value):
            if self.step is None:
                if self.lo <= value <= self.hi:
                    return None
            elif round(self.lo / self.step) <= round(value / self.step) <= round(
                    self.hi / self.step):
                return None
        steps = "" if self.step is None else f" in steps of {self.step:g}"
        return (f"{value!r} {self.unit} does not fit signal {self.name}; valid is "
                f"[{self.lo:.10g}, {self.hi:.10g}] {self.unit}{steps}")


@dataclass(frozen=True)
class LoadRange:
    """The ranges of a wire's ten load values (:data:`NAMES` order)."""

    fields: tuple[Field, ...]
    label: str

    def error(self, payload) -> str | None:
        """Why this wire cannot carry ``payload`` (a :class:`iem.payload.Payload`), naming
        the value and its valid range, or None if it can."""
        for field, value in zip(self.fields, values(payload), strict=True):
            why = field.error(value)
            if why:
                return f"{self.label}: {why}"
        mass = self.fields[0]
        if mass.step is not None and round(float(payload.mass) / mass.step) == 0:
            return (f"{self.label}: payload mass {payload.mass!r} kg rounds to 0 on the wire "
                    f"(which means 'no load'); valid is >= {mass.step:g} kg, or the empty "
                    "load")
        return None


def values(payload) -> tuple[float, ...]:
    """The ten values of ``payload`` as a link writes them: mass, CoM, inertia about the
    CoM."""
    return (payload.mass, *payload.com, *payload.inertia)


FLOAT64 = LoadRange(tuple(Field(n, 0.0 if n == "Mass" else -math.inf, math.inf, u)
                          for n, u in zip(NAMES, UNITS, strict=True)), "float64 values")
"""A wire of doubles: any finite value, a mass not below 0."""


@functools.cache
def of_profile(profile: str) -> LoadRange:
    """The range of the load command of the CAN wire profile ``profile`` (its DBC
    signals)."""
    from .protocol import profile as get_profile

    command = get_profile(profile).command
    fields = command.frame.fields
    out = []
    for name, unit in zip(NAMES, UNITS, strict=True):
        f = fields[name]
        out.append(Field(name, f.raw_min * f.scale, f.raw_max * f.scale, unit, f.scale))
    return LoadRange(tuple(out), f"{command.frame.label}")


def of_declared(declared: str, profile: str = "fd") -> LoadRange | None:
    """The range a link kind declares (:attr:`firmware_bridge.links.LinkKind.load_range`:
    ``"dbc"``, ``"float64"`` or ``""``) with CAN wire profile ``profile``; None for a kind
    that writes no loads. :meth:`firmware_bridge.links.LinkKind.wire_range` asks it."""
    if declared == "dbc":
        return of_profile(profile)
    return FLOAT64 if declared == "float64" else None
