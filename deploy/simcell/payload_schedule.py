"""What the simulated controller's plant carries when: a schedule of payload changes.

A schedule is a list of ``(t, payload)``: at controller time ``t`` s (from the controller's
start) the plant's payload becomes ``payload`` (a :class:`iem.payload.Payload`, or None:
nothing mounted), as a person swaps the tool between two cycles. On the command line it is
``"T:FILE,T:none,..."`` (:func:`parse_schedule`), each FILE a payload TOML as ``--payload``
takes. :class:`PayloadSchedule` turns it into controller cycles (``round(t / DT)``) and keeps
the record of the changes made.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

from iem.errors import PayloadError
from iem.payload import Payload

SPEC_HELP = ("comma-separated T:FILE or T:none, T the controller time in s (>= 0) from its "
             "start, FILE a payload TOML, none: nothing mounted; e.g. '0:tool.toml,20:none'")
"""What a valid ``--payload-schedule`` is, in words (for --help and errors)."""


def parse_schedule(spec: str) -> list[tuple[float, Payload | None]]:
    """The schedule of a ``"T:FILE,T:none"`` spec, its files loaded (sorted by time).

    Raises:
        PayloadError: a malformed entry, a time that is not a number >= 0, a time given
            twice, or a payload file that cannot be read (naming the entry and what is
            valid).
    """
    from sim.payload import load_payload

    out = []
    for entry in spec.split(","):
        entry = entry.strip()
        t_text, sep, what = entry.partition(":")
        if not sep or not what.strip() or not t_text.strip():
            raise PayloadError(f"payload schedule entry {entry!r}: valid is {SPEC_HELP}")
        try:
            t = float(t_text)
        except ValueError:
            raise PayloadError(f"payload schedule entry {entry!r}: time {t_text.strip()!r} is "
                               f"not a number; valid is {SPEC_HELP}") from None
        what = what.strip()
        out.append((t, None if what.lower() == "none" else load_payload(what)))
    return check_schedule(out)


def check_schedule(schedule: Iterable) -> list[tuple[float, Payload | None]]:
    """``schedule`` as a list sorted by time, each entry checked.

    Raises:
        PayloadError: a time that is not a finite number >= 0, a time given twice, or a
            payload that is neither a physically consistent Payload nor None.
    """
    out = []
    for entry in schedule:
        try:
            t, payload = entry
        except (TypeError, ValueError):
            raise PayloadError(f"payload schedule entry {entry!r}: valid is a pair (t in s, "
                               "Payload or None)") from None
        if isinstance(t, bool) or not isinstance(t, int | float) or not math.isfinite(t) \
                or t < 0:
            raise PayloadError(f"payload schedule time {t!r}: valid is a number of s >= 0 "
                               "from the controller's start")
        if payload is not None:
            if not isinstance(payload, Payload):
                raise PayloadError(f"payload schedule at {t:g} s: {payload!r} is not a "
                                   "Payload; valid is a Payload or None (nothing mounted)")
            payload.check()
        out.append((float(t), payload))
    out.sort(key=lambda e: e[0])
    times = [t for t, _ in out]
    if len(set(times)) != len(times):
        twice = sorted({t for t in times if times.count(t) > 1})
        raise PayloadError(f"payload schedule: time {twice[0]:g} s given twice; valid is one "
                           "payload per time")
    return out


class PayloadSchedule:
    """A checked schedule in controller cycles of ``dt`` s, and the record of what was
    mounted (``mounted``: ``{"t": controller time s, "payload": name or None}`` per change
    made).

    Args:
        schedule: ``[(t, Payload | None), ...]`` (see :func:`check_schedule`).
        dt: the controller's period, s.
    """

    def __init__(self, schedule: Iterable, dt: float) -> None:
        self.entries = check_schedule(schedule)
        self.dt = float(dt)
        self._due = [(round(t / self.dt), p) for t, p in self.entries]
        self._next = 0
        self.mounted: list[dict] = []

    def at_start(self) -> tuple[bool, Payload | None]:
        """``(True, payload)`` if the schedule mounts something at cycle 0, else
        ``(False, None)``."""
        if self._due and self._due[0][0] == 0:
            return True, self._due[0][1]
        return False, None

    def due(self, cycle: int) -> list[Payload | None]:
        """The payloads to mount before controller cycle ``cycle`` steps (usually none),
        each recorded in ``mounted``."""
        out = []
        due = self._due
        while self._next < len(due) and due[self._next][0] <= cycle:
            payload = due[self._next][1]
            self._next += 1
            out.append(payload)
            self.mounted.append({"t": cycle * self.dt,
                                 "payload": None if payload is None else payload.name})
        return out
