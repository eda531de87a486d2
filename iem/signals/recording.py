"""Recorded joint states as arrays (:class:`Recording`), checked once, whatever they were
read from; :mod:`iem.signals.offline` makes them into the signals of an offline fit.

numpy only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InvalidInputError
from ..types import N_JOINTS


@dataclass(frozen=True)
class Recording:
    """Recorded joint states as arrays.

    Attributes:
        t: controller time stamps, s (N), increasing.
        q: joint positions, rad (N, 7).
        dq: joint velocities, rad/s (N, 7).
        tau: measured link-side joint torques, N·m (N, 7).
    """

    t: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    tau: np.ndarray

    def __post_init__(self) -> None:
        t = np.asarray(self.t, dtype=float).reshape(-1)
        arrays = {}
        for name in ("q", "dq", "tau"):
            a = np.asarray(getattr(self, name), dtype=float)
            if a.ndim != 2 or a.shape != (t.shape[0], N_JOINTS):
                raise InvalidInputError(f"recording: {name} must have shape ({t.shape[0]}, "
                                        f"{N_JOINTS}) to match t, got {a.shape}")
            arrays[name] = a
        if t.shape[0] < 2:
            raise InvalidInputError(f"recording: needs at least 2 samples, got {t.shape[0]}")
        if not (np.all(np.isfinite(t)) and all(np.all(np.isfinite(a)) for a in arrays.values())):
            raise InvalidInputError("recording: t, q, dq and tau must be finite")
        if np.any(np.diff(t) <= 0.0):
            k = int(np.flatnonzero(np.diff(t) <= 0.0)[0])
            raise InvalidInputError(f"recording: t must increase strictly; sample {k + 1} "
                                    f"({t[k + 1]!r} s) does not follow {t[k]!r} s")
        object.__setattr__(self, "t", t)
        for name, a in arrays.items():
            object.__setattr__(self, name, a)

    def __len__(self) -> int:
        return self.t.shape[0]

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0])

    @classmethod
    def from_states(cls, states) -> Recording:
        """From :class:`iem.types.JointState` values (e.g. a replay source's)."""
        states = list(states)
        if not states:
            raise InvalidInputError("recording: no joint states")
        return cls(t=np.array([s.t for s in states]), q=np.array([s.q for s in states]),
                   dq=np.array([s.dq for s in states]), tau=np.array([s.tau_J for s in states]))


def as_recording(x) -> Recording:
    """A :class:`Recording` from one, from anything with ``t, q, dq, tau`` attributes (a
    :class:`sim.plant.Rollout`), from a tuple ``(t, q, dq, tau)`` or from joint states."""
    if isinstance(x, Recording):
        return x
    if all(hasattr(x, a) for a in ("t", "q", "dq", "tau")):
        return Recording(x.t, x.q, x.dq, x.tau)
    if isinstance(x, tuple) and len(x) == 4:
        return Recording(*x)
    return Recording.from_states(x)
