"""Joint paths for the simulated arm: the excitation path, the new task path and CSV files.

A :class:`Path` is the reference a controller follows, sampled at ``RATE_HZ`` = 1 kHz:

- ``t``: time stamps in s, ``(N,)``, ``t[k] = k / 1000`` (always starts at 0);
- ``q``: joint positions in rad, ``(N, 7)``;
- ``dq``: joint velocities in rad/s, ``(N, 7)``;
- ``ddq``: joint accelerations in rad/s², ``(N, 7)``.

``q``, ``dq`` and ``ddq`` are analytically consistent: every generated path computes them
from closed-form derivatives, never from finite differences. Arrays are read-only.

:meth:`Path.check_limits` checks ``q_min <= q <= q_max``, ``|dq| <= dq_max`` and
``|ddq| <= ddq_max`` (the arm model's limits, :mod:`sim.description`) and raises
:class:`~iem.errors.PathError` for the first violation in time, naming the joint (1-based), the
time (s), the value and the limit. Every generator below returns a checked path; each takes
``model=``, the arm model (:class:`sim.robot.ArmModel`; None: the default arm model's), whose
limits it keeps and whose home (``description.home``, the Panda's :data:`Q0`) and task
(``description.task``, the Panda's :data:`Q_START`, :data:`Q_END`) it moves around.

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

Path CSV files are read and written by :mod:`sim.path_csv` (:func:`load_path_csv`,
:func:`save_path_csv`, importable from here too); the :class:`Path` type itself is
:mod:`sim.joint_path`'s.
"""

from __future__ import annotations

import math

import numpy as np

from iem.errors import PathError
from iem.types import vec7
from sim.robot import arm_model

from .joint_path import N_JOINTS, RATE_HZ, Path
from .path_csv import CSV_HEADER, MIN_CSV_RATE_HZ, MIN_CSV_ROWS, load_path_csv, save_path_csv

__all__ = ["CALIBRATION_AMPLITUDE", "CALIBRATION_SEED", "CSV_HEADER", "EXCITATION_AMPLITUDE",
           "EXCITATION_HARMONICS", "EXCITATION_PERIOD", "LIMIT_FRACTION", "MIN_CSV_RATE_HZ",
           "MIN_CSV_ROWS", "N_JOINTS", "Q0", "Q_END", "Q_START", "RATE_HZ", "Path",
           "calibration_path", "excitation_path", "linear_path", "load_path_csv",
           "new_task_path", "rest_path", "save_path_csv"]

Q0 = np.array(arm_model().description.home)
"""The default arm model's mid-range configuration the excitation path moves around and
starts and ends at, rad."""
Q0.flags.writeable = False

Q_START = np.array(arm_model().description.task[0])
"""The default arm model's first configuration of the new task path, rad (outside the
excitation's bags)."""
Q_START.flags.writeable = False

Q_END = np.array(arm_model().description.task[1])
"""The default arm model's final configuration of the new task path, rad (outside the
excitation's bags)."""
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


def _time_grid(duration: float, what: str) -> np.ndarray:
    duration = float(duration)
    if not math.isfinite(duration) or duration < 0.0:
        raise PathError(f"{what}: duration must be a finite number of s >= 0, got {duration}")
    return np.arange(round(duration * RATE_HZ) + 1) / RATE_HZ


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


def fourier_series(a, b, omega: float,
                   t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``f, f', f''`` of the series ``sum_k a_k sin(k omega t) + b_k cos(k omega t)`` at
    times ``t``, each ``(N, 7)`` (the excitation path's and :mod:`sim.excite`'s)."""
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
                    name: str = "excitation", model=None) -> Path:
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
    amp = vec7("amplitude", amplitude, PathError, finite=True)
    if np.any(amp < 0.0):
        raise PathError(f"excitation path {name!r}: amplitude must be >= 0 rad, got {amp}")
    m = arm_model() if model is None else model
    q0 = m.description.home
    n_periods = max(1, round(t[-1] / period))
    omega = 2.0 * math.pi * n_periods / t[-1]
    a, b = _constrained_coefficients(np.random.default_rng(seed), int(harmonics))
    # scale on one period at 1 kHz (the peaks repeat every period)
    one = t[: round(t[-1] / n_periods * RATE_HZ) + 1]
    f, df, ddf = fourier_series(a, b, omega, one)
    peak = np.abs(f).max(axis=0)
    room = np.minimum(q0 - m.q_min, m.q_max - q0) * 0.9
    scale = np.minimum.reduce([
        np.minimum(amp, room) / peak,
        LIMIT_FRACTION * m.dq_max / np.abs(df).max(axis=0),
        LIMIT_FRACTION * m.ddq_max / np.abs(ddf).max(axis=0),
    ])
    f, df, ddf = fourier_series(a * scale, b * scale, omega, t)
    return Path(name=name, t=t, q=q0 + f, dq=df, ddq=ddf).check_limits(m)


CALIBRATION_SEED = 11
"""Seed of the calibration motion's Fourier coefficients (not the excitation's)."""
CALIBRATION_AMPLITUDE = np.array([1.2, 0.7, 1.2, 0.75, 1.5, 1.0, 1.8])
"""Target peak offset from ``Q0`` per joint of the calibration motion, rad (the joint range
and 75 % of the velocity and acceleration limits cap it)."""
CALIBRATION_AMPLITUDE.flags.writeable = False


def calibration_path(duration: float = 30.0, seed: int = CALIBRATION_SEED, model=None) -> Path:
    """The bare-arm calibration motion ``iem calibrate`` is meant for: the excitation's
    Fourier series (:func:`excitation_path`) with a wide amplitude on every joint, so that
    gravity, inertia and friction of each joint are seen over much of its range and at
    velocities of both signs (three 10 s periods, 30 s by default)."""
    return excitation_path(duration, seed, amplitude=CALIBRATION_AMPLITUDE, name="calibration",
                           model=model)


def linear_path(q_start, q_end, duration: float, name: str = "linear", model=None) -> Path:
    """Every joint from ``q_start`` to ``q_end`` (rad) in ``duration`` s (> 0) with the
    quintic time scaling ``s(τ) = 10τ³ - 15τ⁴ + 6τ⁵``, ``τ = t / duration``: a straight line
    in joint space, at rest (zero velocity and acceleration) at both ends."""
    q_a, q_b = (vec7(n, v, PathError, finite=True)
                for n, v in (("q_start", q_start), ("q_end", q_end)))
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
                ddq=np.outer(dds, dq_total)).check_limits(model)


def new_task_path(q_start=None, q_end=None, duration: float = 6.0,
                  name: str = "new-task", model=None) -> Path:
    """The paper's novel task path: all joints from ``q_start`` (default :data:`Q_START`) to
    ``q_end`` (default :data:`Q_END`) in ``duration`` s (default 6), with the quintic time
    scaling of :func:`linear_path`."""
    task = (arm_model() if model is None else model).description.task
    return linear_path(task[0] if q_start is None else q_start,
                       task[1] if q_end is None else q_end,
                       duration, name=name, model=model)


def rest_path(q, duration: float, name: str = "rest", model=None) -> Path:
    """Standing still at ``q`` (rad) for ``duration`` s (>= 0)."""
    q = vec7("q", q, PathError, finite=True)
    t = _time_grid(duration, f"path {name!r}")
    zeros = np.zeros((t.shape[0], N_JOINTS))
    return Path(name=name, t=t, q=zeros + q, dq=zeros, ddq=zeros).check_limits(model)
