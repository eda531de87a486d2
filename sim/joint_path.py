"""The joint path a controller follows (:class:`Path`), sampled at ``RATE_HZ`` = 1 kHz: its
arrays (read-only), its check against the arm model's limits, joining two paths and slicing one.
The paths themselves are :mod:`sim.paths`'s."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from iem.errors import PathError
from iem.types import NOMINAL_RATE_HZ
from sim.robot import ArmModel, arm_model

RATE_HZ = NOMINAL_RATE_HZ
"""Sample rate of every :class:`Path`, Hz."""

N_JOINTS = 7

AT_REST_TOL = 1e-9
"""How close two paths must meet, and how still they must be there, to be joined."""
TIME_TOL = 1e-9
"""Slack on times given in s (a slice's ends, a path file's intervals)."""


def frozen_array(name: str, value, shape: tuple[int | None, ...]) -> np.ndarray:
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise PathError(f"{name} must be an array of numbers, got {type(value).__name__}") from exc
    ok = arr.ndim == len(shape) and all(e is None or e == s for e, s in zip(shape, arr.shape,
                                                                              strict=True))
    if not ok:
        want = str(tuple("N" if e is None else e for e in shape)).replace("'", "")
        raise PathError(f"{name} must have shape {want}, got {arr.shape}")
    arr.flags.writeable = False
    return arr


def _pair(value: float, limit: float) -> tuple[str, str]:
    """Format a value and its limit with 3 decimals, or as many as the limit needs (up to 6),
    or more if the two would look equal."""
    digits = next((d for d in range(3, 6) if round(limit, d) == limit), 6)
    for d in range(digits, 13):
        a, b = f"{value:.{d}f}", f"{limit:.{d}f}"
        if a != b:
            return a, b
    return repr(float(value)), repr(float(limit))


@dataclass(frozen=True, eq=False)
class Path:
    """Joint path sampled at 1 kHz.

    Attributes:
        name: a label used in messages.
        t: time stamps in s, ``(N,)``, ``t[k] = k / RATE_HZ`` (starts at 0).
        q: joint positions in rad, ``(N, 7)``.
        dq: joint velocities in rad/s, ``(N, 7)``.
        ddq: joint accelerations in rad/s², ``(N, 7)``.

    Arrays are copied and made read-only. Equality is identity (arrays do not compare as one).
    """

    name: str
    t: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    ddq: np.ndarray

    def __post_init__(self) -> None:
        t = frozen_array("t", self.t, (None,))
        n = t.shape[0]
        if n < 1:
            raise PathError("t must have at least one sample, got shape (0,)")
        for field in ("q", "dq", "ddq"):
            value = frozen_array(field, getattr(self, field), (n, N_JOINTS))
            object.__setattr__(self, field, value)
        object.__setattr__(self, "t", t)
        for field in ("t", "q", "dq", "ddq"):
            if not np.all(np.isfinite(getattr(self, field))):
                raise PathError(f"path {self.name!r}: {field} must be finite (found NaN or inf)")
        expected = np.arange(n) / RATE_HZ
        if np.max(np.abs(t - expected)) > 1e-6:
            k = int(np.argmax(np.abs(t - expected)))
            raise PathError(f"path {self.name!r}: t must be k / {RATE_HZ:g} s from 0 "
                            f"(1 kHz from t = 0), got t[{k}] = {t[k]!r} s")

    # -- views -----------------------------------------------------------------------------
    @property
    def duration(self) -> float:
        """Time of the last sample, s."""
        return float(self.t[-1])

    def __len__(self) -> int:
        return int(self.t.shape[0])

    # -- checks ----------------------------------------------------------------------------
    def first_violation(self, model: ArmModel | None = None) -> tuple[int, str] | None:
        """``(sample index, message)`` of the first limit violation in time, or None."""
        m = model if model is not None else arm_model()
        kinds = (
            ("position", "rad", self.q, m.q_min, m.q_max),
            ("velocity", "rad/s", self.dq, -m.dq_max, m.dq_max),
            ("acceleration", "rad/s²", self.ddq, -m.ddq_max, m.ddq_max),
        )
        best: tuple[int, int, int] | None = None  # (sample, kind, joint)
        for kind_no, (_, _, values, lo, hi) in enumerate(kinds):
            bad = (values < lo) | (values > hi)
            rows = np.flatnonzero(bad.any(axis=1))
            if rows.size:
                k = int(rows[0])
                cand = (k, kind_no, int(np.flatnonzero(bad[k])[0]))
                if best is None or cand[0] < best[0]:
                    best = cand
        if best is None:
            return None
        k, kind_no, j = best
        kind, unit, values, lo, hi = kinds[kind_no]
        v = float(values[k, j])
        side = "" if kind_no else ("upper " if v > hi[j] else "lower ")
        limit, verb = (float(hi[j]), "exceeds") if v > hi[j] else (float(lo[j]), "is below")
        verb = f"{verb} the {side}limit"
        vs, ls = _pair(v, limit)
        rng = f"{float(lo[j]):g} .. {float(hi[j]):g}"
        return k, (f"path {self.name!r}: joint {j + 1} {kind} {vs} {unit} {verb} {ls} {unit} "
                   f"at t={self.t[k]:.3f} s (valid is {rng} {unit})")

    def check_limits(self, model: ArmModel | None = None) -> Path:
        """Raise :class:`PathError` at the first position, velocity or acceleration limit
        violation in time (joint 1-based, time in s, value and limit); return self if fine.
        Limits come from ``model`` or, if None, the default arm model
        (:func:`sim.robot.arm_model`)."""
        found = self.first_violation(model)
        if found is not None:
            raise PathError(found[1])
        return self

    # -- combinations ----------------------------------------------------------------------
    def then(self, other: Path, name: str | None = None) -> Path:
        """This path followed by ``other``; time continues at 1 kHz.

        ``other`` must start where this path ends (q equal within 1e-9 rad) and both must be at
        rest there (dq and ddq within 1e-9). The shared sample appears once, so the duration
        is the sum of both durations.
        """
        gap = float(np.max(np.abs(other.q[0] - self.q[-1])))
        if gap > AT_REST_TOL:
            raise PathError(
                f"cannot append path {other.name!r} to {self.name!r}: it starts at "
                f"{np.round(other.q[0], 6).tolist()} rad but {self.name!r} ends at "
                f"{np.round(self.q[-1], 6).tolist()} rad (largest gap {gap:.3g} rad); "
                f"the start must equal the end within {AT_REST_TOL:g} rad")
        for who, k, p in ((self.name, -1, self), (other.name, 0, other)):
            moving = max(float(np.max(np.abs(p.dq[k]))), float(np.max(np.abs(p.ddq[k]))))
            if moving > AT_REST_TOL:
                where = "end" if k == -1 else "start"
                raise PathError(
                    f"cannot join {self.name!r} and {other.name!r}: {who!r} is not at rest at "
                    f"its {where} (largest |dq| or |ddq| is {moving:.3g}); both must be at rest "
                    f"(within {AT_REST_TOL:g}) where they meet")
        n = len(self) + len(other) - 1
        return Path(
            name=name if name is not None else f"{self.name}+{other.name}",
            t=np.arange(n) / RATE_HZ,
            q=np.vstack((self.q, other.q[1:])),
            dq=np.vstack((self.dq, other.dq[1:])),
            ddq=np.vstack((self.ddq, other.ddq[1:])),
        )

    def slice(self, t0: float, t1: float) -> Path:
        """The samples with ``t0 <= t <= t1`` (s), re-timed to start at 0.

        Valid is ``0 <= t0 <= t1 <= duration``; times are rounded to the nearest sample.
        """
        t0, t1 = float(t0), float(t1)
        if not (math.isfinite(t0) and math.isfinite(t1)) or not (
                -TIME_TOL <= t0 <= t1 <= self.duration + TIME_TOL):
            raise PathError(f"path {self.name!r}: slice({t0}, {t1}) is out of range; valid is "
                            f"0 <= t0 <= t1 <= {self.duration:g} s")
        i0, i1 = round(t0 * RATE_HZ), round(t1 * RATE_HZ)
        return Path(name=f"{self.name}[{t0:g}:{t1:g}]", t=np.arange(i1 - i0 + 1) / RATE_HZ,
                    q=self.q[i0:i1 + 1], dq=self.dq[i0:i1 + 1], ddq=self.ddq[i0:i1 + 1])
