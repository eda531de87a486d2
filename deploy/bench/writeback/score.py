"""What ``iem bench writeback`` measures of a run, from records alone (no simulation here).

A *load* is what a controller holds: ``{"mass": kg, "com": [x, y, z] m}``, or None for the
empty load (libfranka's ``setLoad`` with mass 0; a mass of at most :data:`EMPTY_KG` counts as
empty too). The *truth* is what the arm carries, as a load of the same form. The controller's
own record says what was in force when: the load it started with, then each command it
applied (``SimController.stats()["applied"]``: ``{"t", "seq", "mass", "com"}``); the schedule
says what was mounted when (``[(t, load), ...]``). Every figure is read from them:

- a load is **correct** when its mass is within :data:`MASS_TOL_KG` of the truth's and its
  CoM within :data:`COM_TOL_M` (the CoM only when both carry a mass: the empty load has none);
- the **time to correct** from ``since``: the earliest time from which the load in force is
  correct through the end of the run, less ``since`` (None: it is not correct at the end);
- a write puts the controller **farther** from the truth when the load it applies errs more
  than the load in force before it did, by more than :data:`FARTHER_KG` in mass or
  :data:`FARTHER_M` in CoM distance (the mass and CoM distance of the two loads to the truth
  at the write's time, not the joint-torque error).
"""

from __future__ import annotations

import math

import numpy as np

MASS_TOL_KG = 0.05
COM_TOL_M = 0.010
"""A load within these of the truth is correct."""
EMPTY_KG = 1e-4
"""A load of at most this mass is the empty load."""
FARTHER_KG = 0.001
FARTHER_M = 0.001
"""A write errs more than the load before it when its error is larger by more than these."""


def load_of(payload) -> dict | None:
    """A :class:`iem.payload.Payload` (or a load dict) as a load; None: the empty load."""
    if payload is None:
        return None
    if isinstance(payload, dict):
        mass, com = float(payload["mass"]), [float(v) for v in payload["com"]]
    else:
        mass, com = float(payload.mass), [float(v) for v in payload.com]
    return None if mass <= EMPTY_KG else {"mass": mass, "com": com}


def load_error(load, truth) -> tuple[float, float | None]:
    """``(mass error kg, CoM distance m or None)`` of ``load`` against ``truth``; the CoM
    distance only when both carry a mass."""
    load, truth = load_of(load), load_of(truth)
    m = 0.0 if load is None else load["mass"]
    m_true = 0.0 if truth is None else truth["mass"]
    if load is None or truth is None:
        return abs(m - m_true), None
    return abs(m - m_true), float(np.linalg.norm(np.subtract(load["com"], truth["com"])))


def correct(load, truth) -> bool:
    """Within :data:`MASS_TOL_KG` and :data:`COM_TOL_M` of the truth."""
    dm, dc = load_error(load, truth)
    return dm <= MASS_TOL_KG and (dc is None or dc <= COM_TOL_M)


def at(timeline: list, t: float):
    """The value of a step ``timeline`` ``[(t0, v0), (t1, v1), ...]`` (sorted) at ``t``:
    the last entry at or before ``t`` (the first entry's before it)."""
    value = timeline[0][1]
    for when, v in timeline:
        if when > t:
            break
        value = v
    return value


def in_force_timeline(initial, applied: list[dict]) -> list:
    """``[(t, load)]``: the load the controller started with (at time 0), then each command
    it applied."""
    return [(0.0, load_of(initial))] + [(float(a["t"]), load_of(a)) for a in applied]


def truth_timeline(schedule) -> list:
    """``[(t, load)]`` of a payload schedule ``[(t, Payload or None), ...]``."""
    return [(float(t), load_of(p)) for t, p in sorted(schedule, key=lambda e: e[0])]


def time_to_correct(initial, applied: list[dict], schedule, since: float,
                    end: float) -> float | None:
    """Seconds from ``since`` until the load in force is correct and stays so through
    ``end`` (0: it already is at ``since``); None: it is not correct at ``end``."""
    loads = in_force_timeline(initial, applied)
    truths = truth_timeline(schedule)
    events = sorted({since, *(t for t, _ in loads if since < t <= end),
                     *(t for t, _ in truths if since < t <= end)})
    first = None
    for t in reversed(events):
        if not correct(at(loads, t), at(truths, t)):
            break
        first = t
    return None if first is None else first - since


def writes(initial, applied: list[dict], schedule) -> list[dict]:
    """Each applied command against the truth at its time: ``t``, ``mass``, its
    ``mass_error_kg`` and ``com_error_mm`` (None: no CoM to compare), ``correct``, the
    load in force before it (``before_mass_error_kg``, ``before_com_error_mm``) and
    ``farther`` (see the module docstring)."""
    truths = truth_timeline(schedule)
    out = []
    before = load_of(initial)
    for a in applied:
        t, load = float(a["t"]), load_of(a)
        truth = at(truths, t)
        dm, dc = load_error(load, truth)
        bm, bc = load_error(before, truth)
        farther = dm > bm + FARTHER_KG or (dc is not None and bc is not None
                                            and dc > bc + FARTHER_M)
        out.append({"t": t, "mass": 0.0 if load is None else load["mass"],
                    "mass_error_kg": dm, "com_error_mm": None if dc is None else 1e3 * dc,
                    "correct": correct(load, truth), "before_mass_error_kg": bm,
                    "before_com_error_mm": None if bc is None else 1e3 * bc,
                    "farther": bool(farther)})
        before = load
    return out


def worst(rows: list[dict], key: str) -> float | None:
    """The largest ``key`` over ``rows`` (None: none has one)."""
    values = [r[key] for r in rows if r.get(key) is not None]
    return max(values) if values else None


def like(loads, target) -> int:
    """How many of ``loads`` (loads or applied records) are correct for ``target``."""
    return sum(1 for load in loads if load_of(load) is not None and correct(load, target))


def reason_shares(times, reasons, start: float, stop: float) -> dict[str, float]:
    """The share of the gate's decisions between ``start`` and ``stop`` by reason (from a
    per-estimate record of the last decision), largest first."""
    picked = [r for t, r in zip(times, reasons, strict=True) if start <= t <= stop and r]
    if not picked:
        return {}
    counts: dict[str, int] = {}
    for r in picked:
        counts[r] = counts.get(r, 0) + 1
    return {r: n / len(picked) for r, n in sorted(counts.items(), key=lambda kv: -kv[1])}


def held_text(shares: dict[str, float]) -> str:
    """``"gate held: no_change 83 %, ..."``: the three largest of :func:`reason_shares`."""
    return "gate held: " + ", ".join(f"{r} {100 * v:.0f} %" for r, v in
                                     list(shares.items())[:3])


def in_band(load, truth, std) -> bool | None:
    """Whether ``truth`` lies within the 2-sigma band of the estimate a write came from, in
    the parameters the write's mass and CoM come from (mass, and the first moments ``m c``;
    ``std`` paper order); None: no band."""
    std = np.asarray(std, dtype=float)
    if std.shape[0] < 4 or not np.isfinite(std[:4]).all():
        return None
    load, truth = load_of(load), load_of(truth)
    first = np.zeros(4) if load is None else np.r_[load["mass"],
                                                   load["mass"] * np.asarray(load["com"])]
    true = np.zeros(4) if truth is None else np.r_[truth["mass"],
                                                   truth["mass"] * np.asarray(truth["com"])]
    return bool(np.all(np.abs(first - true) <= 2.0 * std[:4]))


def fmt(value, spec: str = ".2f", none: str = "-") -> str:
    """``value`` formatted, or ``none`` for None or NaN."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return none
    return format(value, spec)
