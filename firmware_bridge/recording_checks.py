"""The checks every joint-state recording passes, whatever its format (:mod:`firmware_bridge.
recordings`): at least :data:`MIN_JOINT_STATES` joint states, time stamps that increase
strictly and lie within :data:`MAX_TIME_S` of 0, every value finite; a rate outside the range
the commands take (:data:`iem.signals.rate.RATE_RANGE_HZ`) is logged.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

import numpy as np

from iem.errors import InvalidInputError
from iem.signals.rate import check_rate, detect_rate
from iem.signals.recording import Recording

from .errors import LogFileError

__all__ = ["MAX_TIME_S", "MIN_JOINT_STATES", "checked_recording", "refuse_nonfinite"]

log = logging.getLogger("iem.bridge")

MIN_JOINT_STATES = 10
"""Fewest joint states a recording holds: its rate is the median of its steps, and one block
point takes 10 of them at 1 kHz."""
MAX_TIME_S = 1e10
"""Largest time stamp a recording holds, in magnitude, s: a Unix time until the year 2286,
and far beyond any controller's time since its start."""


def checked_recording(path, t, q, dq, tau, what: Callable[[int], str]) -> Recording:
    """The arrays as a read-only Recording, after the checks every format shares; ``what(k)``
    names joint state ``k`` in the file (a line, a message)."""
    n = t.shape[0]
    if n < MIN_JOINT_STATES:
        raise LogFileError(f"{path}: {n} joint state(s); a recording needs at least "
                           f"{MIN_JOINT_STATES} (its rate is the median of its steps, and one "
                           "block point takes 10 at 1 kHz)")
    far = np.flatnonzero(np.abs(t) > MAX_TIME_S)
    if far.size:
        k = int(far[0])
        raise LogFileError(f"{path}: {what(k)}: t = {float(t[k])!r} s is beyond any "
                           f"recording's time stamps; valid are |t| <= {MAX_TIME_S:g} s (a Unix "
                           "time until the year 2286, or a controller's time since its start)")
    steps = np.diff(t)
    if np.any(steps <= 0.0):
        k = int(np.flatnonzero(steps <= 0.0)[0]) + 1
        how = "repeats" if steps[k - 1] == 0.0 else "goes back from"
        raise LogFileError(f"{path}: {what(k)}: t = {float(t[k])!r} s {how} {what(k - 1)}'s "
                           f"{float(t[k - 1])!r} s; the time stamps of a recording must increase "
                           "strictly (one joint state per controller cycle, in order)")
    rate = detect_rate(t)
    try:
        check_rate(rate)
    except InvalidInputError as exc:
        log.warning("%s: %s", path, exc, extra={"event": "recording_rate"})
    for a in (t, q, dq, tau):
        a.flags.writeable = False  # the source hands out rows as JointState's own arrays
    return Recording(t=t, q=q, dq=dq, tau=tau)


def refuse_nonfinite(path, arrays: dict[str, np.ndarray], what, column) -> None:
    """LogFileError at the first non-finite value of ``arrays`` (``name -> (N,)`` or ``(N,
    n)``): ``what(k)`` names joint state ``k``, ``column(name, j)`` the column."""
    for name, a in arrays.items():
        bad = ~np.isfinite(a)
        if bad.any():
            k = int(np.flatnonzero(bad.reshape(a.shape[0], -1).any(axis=1))[0])
            j = int(np.flatnonzero(bad[k])[0]) if a.ndim == 2 else -1
            value = float(a[k, j] if a.ndim == 2 else a[k])
            raise LogFileError(f"{path}: {what(k)}, {column(name, j)}: {value!r} is not a "
                               "finite number; every value of a recording must be (a single "
                               "non-finite value refuses the whole file)")
