"""The joint states' rate: detected from a recording's time stamps, or given, and the block
size that keeps the estimator's block points at about 100 a second whatever it is.

Arms and their loggers stream joint states at 100 Hz to 1 kHz (a Franka's controller at
1 kHz, the ``classic`` wire profile at 500 Hz, other arms and ``ros2 bag`` logs of them
slower). Every command that reads a recording (``iem calibrate``, ``iem replay``, ``iem
identify``) takes the recording's rate from :func:`detect_rate` unless ``--rate`` gives it,
checks it with :func:`check_rate` and forms block points of :func:`block_frames_for` frames:
the estimator's filters, its equations and the calibration's noise are set for about
:data:`POINTS_PER_S` points a second, and a block of ``round(rate / 100)`` frames keeps them
there (a 200 Hz log: 2 frames a block; 100 Hz: 1; 1 kHz: 10).

numpy only.
"""

from __future__ import annotations

import numpy as np

from ..errors import InvalidInputError
from ..types import NOMINAL_POINT_RATE_HZ

MAX_GAP_S = 0.05
"""A step between two time stamps longer than this is a gap (lost cycles, a restart), s:
the rate is detected without it, and the offline chain (:mod:`iem.signals.offline`) splits a
recording there."""
POINTS_PER_S = NOMINAL_POINT_RATE_HZ
"""The block points a second the estimator is set for (100): its filters' cut-offs, its
equations' rate, the calibration's noise."""
RATE_RANGE_HZ = (100.0, 1000.0)
"""The joint-state rates the commands accept, Hz: at fewer than 100 a second a block point
is a single frame and the points thin below :data:`POINTS_PER_S`; above 1 kHz nothing was
measured."""
RATE_TOL = 0.02
"""How far a rate may lie outside :data:`RATE_RANGE_HZ`, relative (a logger's clock drifts
by a fraction of a percent; its median step is rounded to its clock's tick)."""


def detect_rate(t) -> float:
    """Joint states per second of the time stamps ``t`` (s, increasing): the inverse of the
    median step, the steps longer than :data:`MAX_GAP_S` (gaps) left out unless every step
    is one, then of the steps within half a period of that median (one that spans lost
    cycles would pull it up: 5 % lost at 200 Hz read 199 Hz), rounded to two significant
    figures. The median ignores a logger's jitter, but a logger's steps need not be
    symmetric about the period (the real Panda recording's first 11 s, logged at 1 kHz with
    steps of 0.8-1.6 ms, have a median step of 0.98 ms); the rounding reads them, and a
    float's last bits (a 1 ms step read back from text is 0.99999999999945 ms), as the rate
    the arm runs at, so that a 200 Hz log is 200 Hz, in blocks of 2 frames that make exactly
    the 100 points a second a model trained with ``--rate 200`` expects, and an arm file
    calibrated on it carries the noise of 100 equations a second.

    Raises:
        InvalidInputError: fewer than two time stamps, or none that increase.
    """
    steps = np.diff(np.asarray(t, dtype=float).reshape(-1))
    steps = steps[steps > 0.0]
    if not steps.size:
        raise InvalidInputError("a rate needs at least two increasing time stamps")
    short = steps[steps <= MAX_GAP_S]
    first = float(np.median(short if short.size else steps))
    # lost cycles make steps of two or three periods, late ones a short step and a long one:
    # only steps within half a period of the first median count
    core = steps[(steps > 0.5 * first) & (steps < 1.5 * first)]
    rate = 1.0 / float(np.median(core))
    return float(f"{rate:.2g}")


def block_frames_for(rate_hz: float) -> int:
    """Frames per block point at ``rate_hz`` joint states per second:
    ``max(1, round(rate_hz / 100))``, so that block points come at about
    :data:`POINTS_PER_S` a second."""
    return max(1, round(float(rate_hz) / POINTS_PER_S))


def check_rate(rate_hz: float, what: str = "the joint states") -> float:
    """``rate_hz`` as a float if it lies in :data:`RATE_RANGE_HZ` (within :data:`RATE_TOL`).

    Raises:
        InvalidInputError: naming ``what``, the rate and the valid range.
    """
    low, high = RATE_RANGE_HZ
    rate = float(rate_hz)
    if not low * (1.0 - RATE_TOL) <= rate <= high * (1.0 + RATE_TOL):
        raise InvalidInputError(f"{what} at {rate:.4g} Hz: valid rates are {low:g} Hz to "
                                f"{high:g} Hz (joint states a second)")
    return rate


def rate_line(rate_hz: float, frames: int, detected: bool, what: str = "recording") -> str:
    """The line the commands print: ``recording at 200 Hz (detected), block points of 2
    frames: 100 per s``."""
    how = "detected" if detected else "given"
    return (f"{what} at {rate_hz:.4g} Hz ({how}), block points of {frames} frame"
            f"{'' if frames == 1 else 's'}: {rate_hz / frames:.4g} per s")
