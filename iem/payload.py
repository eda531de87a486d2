"""The payload value type: mass, centre of mass and inertia (numpy only).

Conventions (libfranka's ``setLoad``):

- ``com``: centre of mass in the flange frame (Franka's F, i.e. ``panda_link8``), in m.
- ``inertia``: inertia tensor about the centre of mass, in flange axes, in kg·m².
- ``phi``: the paper's parameter vector ``[m, m*rx, m*ry, m*rz, Ixx, Ixy, Ixz, Iyy, Iyz, Izz]``
  with the inertia taken about the *flange origin* (parallel-axis shift of ``inertia``).

It lives with the other value types that cross the packages' seams (:mod:`iem.types`), so
that the bridge and the safety gate use it without the simulation; its file format (TOML)
is :mod:`sim.payload`'s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .errors import PayloadError

_TRIANGLE_TOL = 1e-12


def _sym(i6) -> np.ndarray:
    """3x3 symmetric matrix from ``[Ixx, Ixy, Ixz, Iyy, Iyz, Izz]``."""
    xx, xy, xz, yy, yz, zz = (float(v) for v in i6)
    return np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])


def _six(matrix: np.ndarray) -> tuple[float, ...]:
    """``[Ixx, Ixy, Ixz, Iyy, Iyz, Izz]`` from a 3x3 matrix."""
    m = matrix
    return (m[0, 0], m[0, 1], m[0, 2], m[1, 1], m[1, 2], m[2, 2])


def _skew_sq(c: np.ndarray) -> np.ndarray:
    """``S(c)^T S(c) = |c|^2 E - c c^T``: the parallel-axis term per unit mass."""
    return float(c @ c) * np.eye(3) - np.outer(c, c)


@dataclass(frozen=True)
class Payload:
    """A rigid payload on the flange.

    Attributes:
        name: a label, free text.
        mass: in kg.
        com: centre of mass in the flange frame, in m (3 values).
        inertia: about the CoM in flange axes, kg·m², as ``(Ixx, Ixy, Ixz, Iyy, Iyz, Izz)``.
    """

    name: str
    mass: float
    com: tuple[float, float, float]
    inertia: tuple[float, float, float, float, float, float]

    def __post_init__(self) -> None:
        com = tuple(float(v) for v in np.asarray(self.com, dtype=float).reshape(-1))
        inertia = np.asarray(self.inertia, dtype=float)
        if inertia.shape == (3, 3):
            inertia = np.array(_six(inertia))
        inertia = tuple(float(v) for v in inertia.reshape(-1))
        if len(com) != 3:
            raise PayloadError(f"com must have 3 entries [x, y, z] in m, got {len(com)}")
        if len(inertia) != 6:
            raise PayloadError(
                "inertia must have 6 entries [Ixx, Ixy, Ixz, Iyy, Iyz, Izz] in kg·m², "
                f"got {len(inertia)}"
            )
        object.__setattr__(self, "mass", float(self.mass))
        object.__setattr__(self, "com", com)
        object.__setattr__(self, "inertia", inertia)

    # -- views ---------------------------------------------------------------------------
    @property
    def inertia_matrix(self) -> np.ndarray:
        """Inertia about the CoM as a 3x3 matrix, kg·m²."""
        return _sym(self.inertia)

    def inertia_about_flange(self) -> np.ndarray:
        """Inertia about the flange origin (parallel-axis theorem), 3x3, kg·m²."""
        return self.inertia_matrix + self.mass * _skew_sq(np.asarray(self.com))

    def to_phi(self) -> np.ndarray:
        """The paper's 10 parameters (inertia about the flange origin)."""
        c = np.asarray(self.com)
        return np.concatenate(([self.mass], self.mass * c, _six(self.inertia_about_flange())))

    @classmethod
    def from_phi(cls, phi, name: str = "estimate") -> Payload:
        """Inverse of :meth:`to_phi`. Raises :class:`PayloadError` if the mass is not > 0."""
        phi = np.asarray(phi, dtype=float).reshape(-1)
        if phi.shape != (10,):
            raise PayloadError(f"phi must have 10 entries, got {phi.shape[0]}")
        m = float(phi[0])
        if not m > 0.0:
            raise PayloadError(f"phi mass must be > 0 kg to recover a CoM, got {m}")
        c = phi[1:4] / m
        inertia_c = _sym(phi[4:]) - m * _skew_sq(c)
        return cls(name=name, mass=m, com=tuple(c), inertia=_six(inertia_c))

    def set_load_args(self) -> tuple[float, list[float], list[float]]:
        """Arguments of libfranka's ``Robot::setLoad(load_mass, F_x_Cload, load_inertia)``.

        Returns mass in kg, the CoM in the flange frame in m, and the inertia about the CoM
        as 9 values in column-major order (kg·m²).
        """
        return self.mass, list(self.com), list(self.inertia_matrix.flatten(order="F"))

    @classmethod
    def from_set_load(cls, mass, F_x_Cload, load_inertia, name: str = "set_load") -> Payload:
        """Inverse of :meth:`set_load_args` (``load_inertia`` column-major, 9 values)."""
        inertia = np.asarray(load_inertia, dtype=float).reshape(3, 3, order="F")
        return cls(name=name, mass=mass, com=tuple(F_x_Cload), inertia=_six(inertia))

    # -- physics -------------------------------------------------------------------------
    def consistency_violations(self) -> list[str]:
        """Every physical-consistency condition this payload fails, in words (empty: fine)."""
        problems = []
        values = [self.mass, *self.com, *self.inertia]
        if not all(math.isfinite(v) for v in values):
            return ["all values must be finite numbers (found NaN or inf)"]
        if not self.mass > 0.0:
            problems.append(f"mass must be > 0 kg, got {self.mass:g}")
        eig = np.linalg.eigvalsh(self.inertia_matrix)
        if not eig[0] > 0.0:
            problems.append(
                "inertia about the CoM must be positive definite, "
                f"smallest principal moment is {eig[0]:.3g} kg·m²"
            )
        else:
            a, b, c = eig
            scale = max(c, 1e-300)
            if a + b < c * (1 - _TRIANGLE_TOL) - _TRIANGLE_TOL * scale:
                problems.append(
                    "principal moments must satisfy the triangle inequality "
                    f"(I1 + I2 >= I3), got {a:.4g} + {b:.4g} < {c:.4g} kg·m²"
                )
        return problems

    def is_consistent(self) -> bool:
        """True if the payload is physically possible (see :meth:`check`)."""
        return not self.consistency_violations()

    def check(self) -> Payload:
        """Raise :class:`PayloadError` naming every failed condition; return self if fine."""
        problems = self.consistency_violations()
        if problems:
            raise PayloadError(f"payload {self.name!r} is not physically consistent: "
                               + "; ".join(problems))
        return self

    def with_name(self, name: str) -> Payload:
        return Payload(name=name, mass=self.mass, com=self.com, inertia=self.inertia)


# -- files ---------------------------------------------------------------------------------


def set_load_values(payload: Payload | None) -> tuple[float, list[float], list[float]]:
    """libfranka's ``setLoad`` arguments of ``payload`` (:meth:`Payload.set_load_args`) as
    plain floats; None, the empty load: mass 0 and zeros."""
    if payload is None:
        return 0.0, [0.0] * 3, [0.0] * 9
    mass, com, inertia = payload.set_load_args()
    return float(mass), [float(v) for v in com], [float(v) for v in inertia]
