"""Joint paths for the simulated Panda: the excitation path, the new task path and CSV files.

A :class:`Path` is the reference a controller follows, sampled at ``RATE_HZ`` = 1 kHz:

- ``t``: time stamps in s, ``(N,)``, ``t[k] = k / 1000`` (always starts at 0);
- ``q``: joint positions in rad, ``(N, 7)``;
- ``dq``: joint velocities in rad/s, ``(N, 7)``;
- ``ddq``: joint accelerations in rad/s², ``(N, 7)``.

``q``, ``dq`` and ``ddq`` are analytically consistent: every generated path computes them
from closed-form derivatives, never from finite differences. Arrays are read-only.

:meth:`Path.check_limits` checks ``q_min <= q <= q_max``, ``|dq| <= dq_max`` and
``|ddq| <= ddq_max`` (the Panda's datasheet limits, :mod:`sim.robot`) and raises
:class:`~iem.errors.PathError` for the first violation in time, naming the joint (1-based), the
time (s), the value and the limit. Every generator below returns a checked path.

The paths of the paper (Taie et al. 2024, sections 4.1 and 5.2):

- :func:`excitation_path`: the training path. Per joint a finite Fourier series with 5
  harmonics of a base frequency of 0.1 Hz (a 10 s period; the default 20 s are two periods)
  around the mid-range configuration ``Q0 = [0, -0.3, 0, -2.2, 0, 2.0, 0.8]`` rad. The seeded
  coefficients are constrained so the series and its first two derivatives vanish at every
  period boundary, so the path starts and ends at rest at ``Q0``. Each joint is scaled to a
  target amplitude, capped at ``LIMIT_FRACTION`` (75 %) of its velocity and acceleration limits.
  With the paper's bag router (30° in joint space and 0.2 m at the flange) the default path
  forms 4 bags, as the paper's excitation path does.
- :func:`new_task_path`: the novel task path, every joint moving from
  ``Q_START = [-1.0, 0.2, 0.5, -1.6, 0.5, 1.6, 0.0]`` to
  ``Q_END = [1.2, 0.4, -0.6, -1.4, 0.7, 2.6, -0.5]`` rad in 6 s with the quintic
  (minimum-jerk) time scaling ``s(τ) = 10τ³ - 15τ⁴ + 6τ⁵``, at rest at both ends. It is a task
  in a part of the workspace the excitation path never reaches: routed after the excitation
  path, none of its points falls inside an excitation bag, so it forms new bags from its first
  point on (the paper's point: a new task needs no identification motion). To run it after
  the excitation, join them with a transfer, e.g.
  ``excitation_path().then(linear_path(Q0, Q_START, 4.0)).then(new_task_path())``.
- :func:`linear_path` is that shape between any two configurations; :func:`rest_path` stands
  still (useful before and after a motion).

Path CSV files (:func:`load_path_csv`, :func:`save_path_csv`)::

    t,q1,q2,q3,q4,q5,q6,q7
    0.0,0.0,-0.3,0.0,-2.2,0.0,2.0,0.8
    0.01,...

- the header is exactly ``t,q1,q2,q3,q4,q5,q6,q7`` (spaces around the names are allowed);
- ``t`` in s, strictly increasing, every interval at most 0.01 s (a rate of at least 100 Hz);
- ``q1..q7`` in rad; every value a finite number; at least 4 data rows; blank lines ignored;
  UTF-8 text (a leading byte-order mark is allowed).

A loaded file is shifted to start at t = 0 and resampled to 1 kHz up to its last sample with a
not-a-knot cubic spline per joint (``scipy.interpolate.CubicSpline``); ``dq`` and ``ddq`` are
the spline's derivatives. Then the limits are checked. Every problem raises
:class:`~iem.errors.PathError` naming the file, the line (1-based, the header is line 1), the
column where relevant, and what would be valid.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path as FsPath

import numpy as np

from iem.errors import PathError
from iem.types import NOMINAL_RATE_HZ
from sim.robot import PandaModel, panda

RATE_HZ = NOMINAL_RATE_HZ
"""Sample rate of every :class:`Path`, Hz."""

N_JOINTS = 7

Q0 = np.array([0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.8])
"""Mid-range configuration the excitation path moves around and starts and ends at, rad."""
Q0.flags.writeable = False

Q_START = np.array([-1.0, 0.2, 0.5, -1.6, 0.5, 1.6, 0.0])
"""First configuration of the default new task path, rad (outside the excitation's bags)."""
Q_START.flags.writeable = False

Q_END = np.array([1.2, 0.4, -0.6, -1.4, 0.7, 2.6, -0.5])
"""Final configuration of the default new task path, rad (outside the excitation's bags)."""
Q_END.flags.writeable = False

EXCITATION_PERIOD = 10.0
"""Period of the excitation's Fourier series, s (base frequency 0.1 Hz)."""
EXCITATION_HARMONICS = 5
"""Harmonics per joint in the excitation's Fourier series."""
EXCITATION_AMPLITUDE = np.array([0.32, 0.22, 0.32, 0.27, 0.37, 0.27, 0.42])
"""Target peak offset from ``Q0`` per joint, rad (before the velocity/acceleration caps).

Tuned so the paper's bag router (30° in joint space, 0.2 m at the flange) splits the default
excitation path (seed 0, 20 s) into 4 bags, as the paper's excitation path is split."""
EXCITATION_AMPLITUDE.flags.writeable = False
LIMIT_FRACTION = 0.75
"""Largest fraction of the velocity and acceleration limits the excitation path uses."""

CSV_HEADER = ("t", "q1", "q2", "q3", "q4", "q5", "q6", "q7")
MIN_CSV_RATE_HZ = 100.0
"""Lowest sample rate a path file may have, Hz."""
MIN_CSV_ROWS = 4

_AT_REST_TOL = 1e-9
_TIME_TOL = 1e-9


def _frozen(name: str, value, shape: tuple[int | None, ...]) -> np.ndarray:
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


def _vec7(name: str, value) -> np.ndarray:
    arr = _frozen(name, np.asarray(value, dtype=float).reshape(-1), (N_JOINTS,))
    if not np.all(np.isfinite(arr)):
        raise PathError(f"{name} must be 7 finite joint positions in rad, got {arr}")
    return arr


def _time_grid(duration: float, what: str) -> np.ndarray:
    duration = float(duration)
    if not math.isfinite(duration) or duration < 0.0:
        raise PathError(f"{what}: duration must be a finite number of s >= 0, got {duration}")
    return np.arange(round(duration * RATE_HZ) + 1) / RATE_HZ


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
        t = _frozen("t", self.t, (None,))
        n = t.shape[0]
        if n < 1:
            raise PathError("t must have at least one sample, got shape (0,)")
        for field in ("q", "dq", "ddq"):
            object.__setattr__(self, field, _frozen(field, getattr(self, field), (n, N_JOINTS)))
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
    def first_violation(self, model: PandaModel | None = None) -> tuple[int, str] | None:
        """``(sample index, message)`` of the first limit violation in time, or None."""
        m = model if model is not None else panda()
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

    def check_limits(self, model: PandaModel | None = None) -> Path:
        """Raise :class:`PathError` at the first position, velocity or acceleration limit
        violation in time (joint 1-based, time in s, value and limit); return self if fine.
        Limits come from ``model`` or, if None, the nominal :func:`sim.robot.panda`."""
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
        if gap > _AT_REST_TOL:
            raise PathError(
                f"cannot append path {other.name!r} to {self.name!r}: it starts at "
                f"{np.round(other.q[0], 6).tolist()} rad but {self.name!r} ends at "
                f"{np.round(self.q[-1], 6).tolist()} rad (largest gap {gap:.3g} rad); "
                f"the start must equal the end within {_AT_REST_TOL:g} rad")
        for who, k, p in ((self.name, -1, self), (other.name, 0, other)):
            moving = max(float(np.max(np.abs(p.dq[k]))), float(np.max(np.abs(p.ddq[k]))))
            if moving > _AT_REST_TOL:
                where = "end" if k == -1 else "start"
                raise PathError(
                    f"cannot join {self.name!r} and {other.name!r}: {who!r} is not at rest at "
                    f"its {where} (largest |dq| or |ddq| is {moving:.3g}); both must be at rest "
                    f"(within {_AT_REST_TOL:g}) where they meet")
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
                -_TIME_TOL <= t0 <= t1 <= self.duration + _TIME_TOL):
            raise PathError(f"path {self.name!r}: slice({t0}, {t1}) is out of range; valid is "
                            f"0 <= t0 <= t1 <= {self.duration:g} s")
        i0, i1 = round(t0 * RATE_HZ), round(t1 * RATE_HZ)
        return Path(name=f"{self.name}[{t0:g}:{t1:g}]", t=np.arange(i1 - i0 + 1) / RATE_HZ,
                    q=self.q[i0:i1 + 1], dq=self.dq[i0:i1 + 1], ddq=self.ddq[i0:i1 + 1])


# -- generators ----------------------------------------------------------------------------
def _constrained_coefficients(rng: np.random.Generator, harmonics: int) -> tuple:
    """Fourier coefficients ``a_k, b_k`` (k = 1..H, one column per joint) of
    ``f(t) = sum_k a_k sin(k w t) + b_k cos(k w t)`` with ``f = f' = f'' = 0`` at t = 0:
    ``sum b_k = 0``, ``sum k a_k = 0`` and ``sum k² b_k = 0`` (least-norm projection)."""
    k = np.arange(1, harmonics + 1, dtype=float)
    a = rng.standard_normal((harmonics, N_JOINTS)) / k[:, None]
    b = rng.standard_normal((harmonics, N_JOINTS)) / k[:, None]
    ca = k[:, None]
    a -= ca @ np.linalg.lstsq(ca, a, rcond=None)[0]
    cb = np.column_stack((np.ones(harmonics), k**2))
    b -= cb @ np.linalg.lstsq(cb, b, rcond=None)[0]
    return a, b


def _fourier(a, b, omega: float, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``f, f', f''`` of the series at times ``t``, each ``(N, 7)``."""
    kw = omega * np.arange(1, a.shape[0] + 1)
    phase = np.outer(t, kw)
    s, c = np.sin(phase), np.cos(phase)
    f = s @ a + c @ b
    df = c @ (a * kw[:, None]) - s @ (b * kw[:, None])
    ddf = -(s @ (a * kw[:, None] ** 2) + c @ (b * kw[:, None] ** 2))
    return f, df, ddf


def excitation_path(duration: float = 20.0, seed: int = 0, *,
                    period: float = EXCITATION_PERIOD,
                    harmonics: int = EXCITATION_HARMONICS,
                    amplitude=EXCITATION_AMPLITUDE,
                    name: str = "excitation") -> Path:
    """The training path: a seeded finite Fourier series per joint around :data:`Q0`.

    ``q_j(t) = Q0_j + s_j f_j(t)`` with ``f_j`` a series of ``harmonics`` harmonics whose
    coefficients (drawn from ``seed``) make ``f``, ``f'`` and ``f''`` vanish at every period
    boundary, so the path starts and ends at rest at ``Q0``. ``s_j`` scales the peak offset
    to ``amplitude[j]`` rad, capped so ``|dq| <= 0.75 dq_max`` and ``|ddq| <= 0.75 ddq_max``.

    Args:
        duration: s, > 0. It holds ``n = max(1, round(duration / period))`` whole periods;
            the period is stretched or shrunk to fit (the caps keep shorter ones in limits).
        seed: seed of the coefficients.
        period: nominal period of the series, s (10 s: a 0.1 Hz base frequency).
        harmonics: number of harmonics, >= 3 (the boundary conditions take 3 of the 2H).
        amplitude: target peak offset from ``Q0`` per joint, rad (7 values, >= 0).
    """
    t = _time_grid(duration, f"excitation path {name!r}")
    if t[-1] <= 0.0:
        raise PathError(f"excitation path {name!r}: duration must be > 0 s, got {duration}")
    if not (math.isfinite(period) and period > 0.0):
        raise PathError(f"excitation path {name!r}: period must be > 0 s, got {period}")
    if int(harmonics) != harmonics or harmonics < 3:
        raise PathError(f"excitation path {name!r}: harmonics must be an integer >= 3, "
                        f"got {harmonics}")
    amp = _vec7("amplitude", amplitude)
    if np.any(amp < 0.0):
        raise PathError(f"excitation path {name!r}: amplitude must be >= 0 rad, got {amp}")
    m = panda()
    n_periods = max(1, round(t[-1] / period))
    omega = 2.0 * math.pi * n_periods / t[-1]
    a, b = _constrained_coefficients(np.random.default_rng(seed), int(harmonics))
    # scale on one period at 1 kHz (the peaks repeat every period)
    one = t[: round(t[-1] / n_periods * RATE_HZ) + 1]
    f, df, ddf = _fourier(a, b, omega, one)
    peak = np.abs(f).max(axis=0)
    room = np.minimum(Q0 - m.q_min, m.q_max - Q0) * 0.9
    scale = np.minimum.reduce([
        np.minimum(amp, room) / peak,
        LIMIT_FRACTION * m.dq_max / np.abs(df).max(axis=0),
        LIMIT_FRACTION * m.ddq_max / np.abs(ddf).max(axis=0),
    ])
    f, df, ddf = _fourier(a * scale, b * scale, omega, t)
    return Path(name=name, t=t, q=Q0 + f, dq=df, ddq=ddf).check_limits(m)


CALIBRATION_SEED = 11
"""Seed of the calibration motion's Fourier coefficients (not the excitation's)."""
CALIBRATION_AMPLITUDE = np.array([1.2, 0.7, 1.2, 0.75, 1.5, 1.0, 1.8])
"""Target peak offset from ``Q0`` per joint of the calibration motion, rad (the joint range
and 75 % of the velocity and acceleration limits cap it)."""
CALIBRATION_AMPLITUDE.flags.writeable = False


def calibration_path(duration: float = 30.0, seed: int = CALIBRATION_SEED) -> Path:
    """The bare-arm calibration motion ``iem calibrate`` is meant for: the excitation's
    Fourier series (:func:`excitation_path`) with a wide amplitude on every joint, so that
    gravity, inertia and friction of each joint are seen over much of its range and at
    velocities of both signs (three 10 s periods, 30 s by default)."""
    return excitation_path(duration, seed, amplitude=CALIBRATION_AMPLITUDE, name="calibration")


def linear_path(q_start, q_end, duration: float, name: str = "linear") -> Path:
    """Every joint from ``q_start`` to ``q_end`` (rad) in ``duration`` s (> 0) with the
    quintic time scaling ``s(τ) = 10τ³ - 15τ⁴ + 6τ⁵``, ``τ = t / duration``: a straight line
    in joint space, at rest (zero velocity and acceleration) at both ends."""
    q_a, q_b = _vec7("q_start", q_start), _vec7("q_end", q_end)
    t = _time_grid(duration, f"path {name!r}")
    if t[-1] <= 0.0:
        raise PathError(f"path {name!r}: duration must be > 0 s, got {duration}")
    T = t[-1]
    tau = t / T
    s = tau**3 * (10.0 - 15.0 * tau + 6.0 * tau**2)
    ds = 30.0 * tau**2 * (1.0 - tau) ** 2 / T
    dds = 60.0 * tau * (1.0 - tau) * (1.0 - 2.0 * tau) / T**2
    dq_total = q_b - q_a
    return Path(name=name, t=t, q=q_a + np.outer(s, dq_total), dq=np.outer(ds, dq_total),
                ddq=np.outer(dds, dq_total)).check_limits()


def new_task_path(q_start=None, q_end=None, duration: float = 6.0,
                  name: str = "new-task") -> Path:
    """The paper's novel task path: all joints from ``q_start`` (default :data:`Q_START`) to
    ``q_end`` (default :data:`Q_END`) in ``duration`` s (default 6), with the quintic time
    scaling of :func:`linear_path`."""
    return linear_path(Q_START if q_start is None else q_start,
                       Q_END if q_end is None else q_end,
                       duration, name=name)


def rest_path(q, duration: float, name: str = "rest") -> Path:
    """Standing still at ``q`` (rad) for ``duration`` s (>= 0)."""
    q = _vec7("q", q)
    t = _time_grid(duration, f"path {name!r}")
    zeros = np.zeros((t.shape[0], N_JOINTS))
    return Path(name=name, t=t, q=zeros + q, dq=zeros, ddq=zeros).check_limits()


# -- files ---------------------------------------------------------------------------------
def _read_text(file) -> tuple[str, str]:
    """``(text, name for messages)`` of a path-like or an open text file."""
    if hasattr(file, "read"):
        where = str(getattr(file, "name", "<stream>"))
        try:
            text = file.read()
        except (OSError, UnicodeDecodeError) as exc:
            raise PathError(f"{where}: cannot read path file: {exc}") from exc
        if isinstance(text, bytes):
            try:
                text = text.decode("utf-8")
            except UnicodeDecodeError as exc:
                raise PathError(f"{where}: path file is not UTF-8 text: {exc}") from exc
        return text.removeprefix("\ufeff"), where
    where = os.fspath(file)
    try:
        return FsPath(where).read_text(encoding="utf-8-sig"), str(where)
    except UnicodeDecodeError as exc:
        raise PathError(f"{where}: path file is not UTF-8 text: {exc}") from exc
    except OSError as exc:
        raise PathError(f"{where}: cannot read path file: {exc.strerror or exc}") from exc


def _parse_csv(text: str, where: str) -> tuple[np.ndarray, np.ndarray]:
    """``(data (M, 8), line number of each row)`` of a path CSV, every problem a PathError."""
    expected = ",".join(CSV_HEADER)
    lines = text.splitlines()
    if not lines or [c.strip() for c in lines[0].split(",")] != list(CSV_HEADER):
        got = repr(lines[0]) if lines else "an empty file"
        raise PathError(f"{where}, line 1: the header must be exactly {expected!r} "
                        f"(t in s, q1..q7 in rad), got {got}")
    rows, numbers = [], []
    prev_t, prev_line = None, 1
    max_dt = 1.0 / MIN_CSV_RATE_HZ
    for line_no, line in enumerate(lines[1:], start=2):
        if not line.strip():
            continue
        cells = line.split(",")
        if len(cells) != len(CSV_HEADER):
            raise PathError(f"{where}, line {line_no}: expected {len(CSV_HEADER)} columns "
                            f"({expected}), got {len(cells)}")
        row = []
        for col, (cell, field) in enumerate(zip(cells, CSV_HEADER, strict=True), start=1):
            unit = "s" if field == "t" else "rad"
            try:
                value = float(cell)
            except ValueError:
                raise PathError(f"{where}, line {line_no}, column {col} ({field}): "
                                f"{cell.strip()!r} is not a number; expected a finite number "
                                f"in {unit}") from None
            if not math.isfinite(value):
                raise PathError(f"{where}, line {line_no}, column {col} ({field}): "
                                f"{cell.strip()!r} is not finite; expected a finite number "
                                f"in {unit}")
            row.append(value)
        t = row[0]
        if prev_t is not None:
            dt = t - prev_t
            if dt <= 0.0:
                raise PathError(f"{where}, line {line_no}, column 1 (t): t = {t!r} s does not "
                                f"increase after t = {prev_t!r} s on line {prev_line}; "
                                "t must be strictly increasing")
            if dt > max_dt + _TIME_TOL:
                raise PathError(f"{where}, line {line_no}, column 1 (t): the interval "
                                f"{dt:.6g} s since line {prev_line} is a rate of "
                                f"{1.0 / dt:.4g} Hz; a path file needs at least "
                                f"{MIN_CSV_RATE_HZ:g} Hz (every interval <= {max_dt:g} s)")
        prev_t, prev_line = t, line_no
        rows.append(row)
        numbers.append(line_no)
    if len(rows) < MIN_CSV_ROWS:
        raise PathError(f"{where}, line {len(lines) + 1}: the file ends after {len(rows)} data "
                        f"row(s); a path file needs at least {MIN_CSV_ROWS} rows after the "
                        "header")
    return np.array(rows), np.array(numbers)


def load_path_csv(file, name: str | None = None) -> Path:
    """Read a path CSV file (see the module docstring), resample it to 1 kHz and check limits.

    ``file`` is a file system path or an open text file. The path is named ``name`` or the
    file's stem. Raises :class:`PathError` naming the file, line and column of any problem.
    """
    from scipy.interpolate import CubicSpline

    text, where = _read_text(file)
    data, line_numbers = _parse_csv(text, where)
    t_file = data[:, 0] - data[0, 0]
    spline = CubicSpline(t_file, data[:, 1:], axis=0, bc_type="not-a-knot")
    t = np.arange(math.floor(t_file[-1] * RATE_HZ + 1e-6) + 1) / RATE_HZ
    path = Path(name=name if name is not None else FsPath(where).stem, t=t, q=spline(t),
                dq=spline(t, 1), ddq=spline(t, 2))
    found = path.first_violation()
    if found is not None:
        k, message = found
        line = int(line_numbers[int(np.argmin(np.abs(t_file - t[k])))])
        raise PathError(f"{where}, near line {line}: {message} (after resampling to 1 kHz)")
    return path


def save_path_csv(path: Path, file) -> None:
    """Write ``t,q1..q7`` (s, rad) at full precision; :func:`load_path_csv` reads it back.

    ``file`` is a file system path or an open text file."""
    out = [",".join(CSV_HEADER)]
    out += [",".join(repr(float(v)) for v in (t, *q)) for t, q in zip(path.t, path.q,
                                                                      strict=True)]
    text = "\n".join(out) + "\n"
    if hasattr(file, "write"):
        file.write(text)
    else:
        FsPath(file).write_text(text, encoding="utf-8")
