"""The ``generic`` family: the tools a cell mounts, not only the paper's container.

The paper's family is one container with steel weights: 0.79 to 2.17 kg, its CoM within
about 4 cm of the flange axis and 2-8 cm along it. A cell mounts grippers, screwdrivers,
suction cups, cameras, bars: from nothing at all to the rated 3 kg, with the CoM up to 15 cm
from the flange. A learner trained on the container guesses from the container for all of
them (a 0.42 kg probe read 0.077 kg off, a 2.4 kg tool with its CoM 0.1 m off-axis 0.058
kg·m off). This family spans what a cell mounts instead.

Each payload is a rigid body built as a real tool is: a body and, for most, an arm or finger
that carries part of the mass sideways; each part a uniform solid cuboid of random edges,
turned by a random rotation, at a random place:

- **mass** uniform in ``[MIN_MASS, MAX_MASS]`` (0.02 to 3 kg);
- **parts**: a body (60-100 % of the mass) centred anywhere in the half ball of 0.15 m on
  the far side of the flange (tools sit on the axis or reach sideways, like a bar or an
  offset gripper), and with probability 0.7 a second part (the rest) at up to 0.15 m from
  the flange;
- **sizes**: a part's density is log-uniform between ``DENSITY`` (a hollow plastic housing
  to solid steel), its volume the mass over that density, its edges that volume's cube root
  times random aspect factors (up to 5:1), so its inertia is that of a real object of its
  mass;
- the whole is rejected and drawn again if its CoM lies farther than ``MAX_COM`` (0.15 m)
  from the flange.

The sum of physically consistent parts is physically consistent (a test checks every member
with Pinocchio's pseudo-inertia). Seeded: the same ``seed`` and ``count`` give the same family.
"""

from __future__ import annotations

import functools

import numpy as np

from sim.payload import Payload

MIN_MASS = 0.02
"""Lightest member, kg (a probe; a bare flange is the empty payload, not a family member)."""
MAX_MASS = 3.0
"""Heaviest member, kg: the Panda's rated payload."""
MAX_COM = 0.15
"""Largest distance of a member's CoM from the flange origin, m."""
DENSITY = (300.0, 7850.0)
"""Range of a part's mean density, kg/m³: a hollow plastic housing to solid steel."""
ASPECT = 0.8
"""A part's edges are the cube root of its volume times ``exp(U(-ASPECT, ASPECT))`` each,
normalised to keep the volume (edge ratios up to about 5:1)."""
COUNT = 77
"""Members of the default family: as many as the paper's, so training costs the same."""
SEED = 20241
"""Seed of the default family."""


def _random_rotation(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _in_half_ball(rng: np.random.Generator) -> np.ndarray:
    """A point uniform in the half ball of radius ``MAX_COM`` on the far side of the flange."""
    while True:
        p = rng.uniform(-MAX_COM, MAX_COM, size=3)
        p[2] = abs(p[2])
        if p @ p <= MAX_COM * MAX_COM:
            return p


def _part(rng: np.random.Generator, mass: float, centre: np.ndarray) -> tuple:
    """``(m, c, I_about_c)`` of a uniform cuboid of random density, shape and orientation."""
    density = np.exp(rng.uniform(*np.log(DENSITY)))
    factors = np.exp(rng.uniform(-ASPECT, ASPECT, size=3))
    a, b, c = (mass / density) ** (1.0 / 3.0) * factors / np.prod(factors) ** (1.0 / 3.0)
    box = mass / 12.0 * np.diag([b * b + c * c, a * a + c * c, a * a + b * b])
    R = _random_rotation(rng)
    return mass, centre, R @ box @ R.T


def _combine(parts) -> tuple[float, np.ndarray, np.ndarray]:
    """Mass, CoM and inertia about the CoM of rigidly joined parts (parallel axes)."""
    mass = sum(m for m, _, _ in parts)
    com = sum(m * c for m, c, _ in parts) / mass
    inertia = np.zeros((3, 3))
    for m, c, I in parts:
        d = c - com
        inertia += I + m * (d @ d * np.eye(3) - np.outer(d, d))
    return mass, com, inertia


def random_tool(rng: np.random.Generator, name: str) -> Payload:
    """One member of the family (see the module docstring)."""
    while True:
        mass = rng.uniform(MIN_MASS, MAX_MASS)
        share = rng.uniform(0.6, 1.0) if rng.random() < 0.7 else 1.0
        body = _in_half_ball(rng)
        parts = [_part(rng, mass * share, body)]
        if share < 1.0:
            direction = rng.normal(size=3)
            direction[2] = abs(direction[2])  # tools reach away from the robot
            direction /= np.linalg.norm(direction)
            parts.append(_part(rng, mass * (1 - share),
                               direction * rng.uniform(0.0, MAX_COM)))
        m, com, inertia = _combine(parts)
        if np.linalg.norm(com) <= MAX_COM:
            six = (inertia[0, 0], inertia[0, 1], inertia[0, 2], inertia[1, 1], inertia[1, 2],
                   inertia[2, 2])
            return Payload(name=name, mass=float(m), com=tuple(float(v) for v in com),
                           inertia=tuple(float(v) for v in six))


@functools.cache
def _generic(count: int, seed: int) -> tuple[Payload, ...]:
    rng = np.random.default_rng(seed)
    return tuple(random_tool(rng, f"generic-{i:03d}") for i in range(count))


def generic_payloads(count: int = COUNT, seed: int = SEED) -> list[Payload]:
    """The ``generic`` family: ``count`` random tools drawn with ``seed``."""
    return list(_generic(int(count), int(seed)))
