"""The checks every joint-state recording passes, whatever its format (:mod:`firmware_bridge.
recordings`): at least two joint states, time stamps that increase strictly, every value
finite; a rate outside the range the commands take (:data:`iem.signals.rate.RATE_RANGE_HZ`)
is logged.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

import numpy as np

from iem.errors import InvalidInputError
from iem.signals.rate import check_rate, detect_rate
from iem.signals.recording import Recording

from .errors import LogFileError

__all__ = ["checked_recording", "refuse_nonfinite"]

log = logging.getLogger("iem.bridge")


def checked_recording(path, t, q, dq, tau, what: Callable[[int], str]) -> Recording:
    """The arrays as a read-only Recording, after the checks every format shares; ``what(k)``
    names joint state ``k`` in the file (a line, a message)."""
    n = t.shape[0]
    if n < 2:
        raise LogFileError(f"{path}: {n} joint state(s); a recording needs at least 2")
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
