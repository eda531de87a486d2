"""What ``iem bench fci`` measures of a run, from the scene's truth log and the client's
records alone (no simulation here).

The scene's log (:meth:`deploy.simcell.FciSim.events`, the robot's time) says what the arm
carried when (``mount``, ``unmount``), when each motion ran, every ``setLoad`` the robot
applied (the load in force: it starts empty) or refused, and a pose every 0.1 s of a motion.
Per payload change (a mount or a release) at ``t_change``, with the motion that follows it
(the one that *carries the change*) ending at ``t_end``, and the next change at ``t_next``:

- **latency**: the time from ``t_end`` to the first instant from which the load in force is
  correct through ``t_next`` (None: never);
- **correct**: within 0.05 kg and 10 mm of the truth (:func:`deploy.bench.writeback.score.
  correct`), or, for a payload under :data:`LIGHT_KG`, leaving at most :data:`TORQUE_TOL_NM`
  of joint torque at the carrying motion's poses;
- **error**: the load in force just before ``t_next`` against the truth: mass (kg), CoM
  distance (mm; both carrying a mass) and the joint torque it leaves at the carrying motion's
  poses (the gravity torque of the difference, the worst joint and pose, N·m);
- **writes**: each ``setLoad`` applied in the interval, and whether it put the robot
  **farther** from the truth than the load it replaced (:func:`deploy.bench.writeback.
  score.writes`); a non-empty load written while the arm is bare counts as a **bare write**;
- **refusals**: the robot's refusals in the interval;
- **held**: for a change never correct, the share of the gate's decisions by reason from
  ``t_end`` to ``t_next`` (from the client's per-point record of the latest decision), what
  held the load that would have been correct.

The callback's cost is the program's own timing of each call (p50, p99, max, µs); the
control loop's pace, the wall time between the starts of consecutive callbacks of a motion
(:func:`arrivals_ms`): franky calls them from the robot's 1 kHz loop, so a late one is a
loop held beyond its cycle (by whatever kept its thread from running: the machine's other
work, or the program's interpreter lock held by another of its threads).
"""

from __future__ import annotations

import numpy as np

from deploy.bench.writeback.score import (
    EMPTY_KG,
    at,
    correct,
    load_error,
    load_of,
    reason_shares,
    writes,
)

LIGHT_KG = 1.0
"""A payload under this mass is judged by the joint torque it leaves."""
TORQUE_TOL_NM = 0.1
"""The joint torque a correct load may leave at the recent poses, N·m (light payloads)."""


def phi_of(load) -> np.ndarray:
    """The paper's ``phi`` of a load dict (mass, com, inertia about the CoM; None: zeros)."""
    from iem.payload import Payload

    if load is None or float(load["mass"]) <= EMPTY_KG:
        return np.zeros(10)
    inertia = load.get("inertia")
    if inertia is not None and len(inertia) == 9:
        return Payload.from_set_load(load["mass"], load["com"], inertia).to_phi()
    p = Payload(name="load", mass=float(load["mass"]), com=tuple(load["com"]),
                inertia=tuple(inertia) if inertia is not None else (0.0,) * 6)
    return p.to_phi()


def torque_error(load, truth, regressors) -> float | None:
    """The worst joint torque (N·m) the difference between ``load`` and ``truth`` makes at
    the poses whose payload regressors ``(P, 7, 10)`` are given (None: no pose)."""
    if regressors is None or len(regressors) == 0:
        return None
    diff = phi_of(load) - phi_of(truth)
    return float(np.abs(np.asarray(regressors) @ diff).max())


def timelines(events: list) -> dict:
    """The scene's log as ``truth`` ``[(t, load)]``, ``in_force`` ``[(t, load)]`` (empty at
    0), ``applied`` (each setLoad: ``{"t", "mass", "com", "inertia"}``), ``refused`` (times),
    ``motions`` ``[(start, end)]`` and ``poses`` ``[(t, q)]``."""
    truth, applied, refused, motions, poses = [(0.0, None)], [], [], [], []
    start = None
    for t, kind, data in events:
        if kind == "mount":
            truth.append((t, {"mass": data["mass"], "com": data["com"],
                              "inertia": data["inertia"]}))
        elif kind == "unmount":
            truth.append((t, None))
        elif kind == "set_load":
            mass, com, inertia = data
            applied.append({"t": t, "mass": mass, "com": com, "inertia": inertia})
        elif kind == "refused":
            refused.append(t)
        elif kind == "motion_start":
            start = t
        elif kind == "motion_end" and start is not None:
            motions.append((start, t))
            start = None
        elif kind == "pose":
            poses.append((t, data))
    in_force = [(0.0, None)] + [(a["t"], load_of(a) and {**load_of(a),
                                                          "inertia": a["inertia"]})
                                for a in applied]
    return {"truth": truth, "in_force": in_force, "applied": applied, "refused": refused,
            "motions": motions, "poses": poses}


def _correct(load, truth, regressors) -> bool:
    if truth is not None and truth["mass"] < LIGHT_KG:
        err = torque_error(load, truth, regressors)
        if err is not None and err <= TORQUE_TOL_NM:
            return True
    return correct(load, truth)


def changes(events: list, regressor, end: float, rows=None, reasons=None) -> list[dict]:
    """Each payload change's figures (see the module docstring); ``regressor(q)`` the arm
    model's payload regressor at rest (7, 10); ``end`` the run's end (robot s); ``rows`` and
    ``reasons`` the client's records (None: no ``held``)."""
    tl = timelines(events)
    marks = tl["truth"][1:]
    out = []
    for i, (t_change, truth) in enumerate(marks):
        t_next = marks[i + 1][0] if i + 1 < len(marks) else end
        carry = next(((a, b) for a, b in tl["motions"] if a >= t_change), None)
        if carry is None or carry[0] >= t_next:
            continue
        t_end = carry[1]
        Y = np.array([regressor(np.asarray(q)) for t, q in tl["poses"]
                      if carry[0] <= t <= carry[1]])
        moments = sorted({t_change, *(a["t"] for a in tl["applied"]
                                      if t_change < a["t"] < t_next)})
        first = None
        for t in reversed(moments):
            if not _correct(at(tl["in_force"], t), truth, Y):
                break
            first = t
        final = at(tl["in_force"], t_next - 1e-9)
        dm, dc = load_error(final, truth)
        inside = [a for a in tl["applied"] if t_change <= a["t"] < t_next]
        before = at(tl["in_force"], t_change)
        judged = writes(before, inside, [(t_change, truth)])
        out.append({
            "t_change": t_change, "truth_mass": 0.0 if truth is None else truth["mass"],
            "motion": [carry[0], t_end], "motion_s": t_end - carry[0],
            "latency_s": None if first is None else first - t_end,
            "correct_at_end": _correct(at(tl["in_force"], t_end), truth, Y),
            "correct": first is not None,
            "mass_error_kg": dm, "com_error_mm": None if dc is None else 1e3 * dc,
            "torque_error_nm": torque_error(final, truth, Y),
            "writes": len(inside), "farther": sum(w["farther"] for w in judged),
            "bare_writes": sum(1 for a in inside if truth is None and a["mass"] > EMPTY_KG),
            "refusals": sum(1 for t in tl["refused"] if t_change <= t < t_next),
            "refusals_moving": sum(1 for t in tl["refused"] if t_change <= t < t_next
                                   and any(a <= t <= b for a, b in tl["motions"])),
            "held": (reason_shares([r[0] for r in rows], reasons, t_end, t_next)
                     if first is None and rows is not None and reasons is not None
                     and len(reasons) == len(rows) else None),
        })
    return out


MOTION_GAP_S = 0.1
"""Callbacks further apart than this are in different motions (the program rests, grasps
or writes between them): not a step of the control loop."""
LATE_MS = 2.0
"""A callback that began this long or more after the one before it: the control loop was
held a cycle or more beyond its 1 ms."""


def arrivals_ms(arrivals_ns) -> dict | None:
    """The control loop's pace seen from the callback: the wall time between the starts of
    consecutive callbacks within a motion, ``{"n", "p50", "p99", "p999", "max", "late"}``
    (ms; ``late``: how many were :data:`LATE_MS` or more), None without any."""
    if arrivals_ns is None or len(arrivals_ns) < 2:
        return None
    gaps = np.diff(np.asarray(arrivals_ns, dtype=float)) / 1e6
    gaps = gaps[gaps < 1e3 * MOTION_GAP_S]
    if gaps.size == 0:
        return None
    return {"n": int(gaps.size), "p50": float(np.percentile(gaps, 50)),
            "p99": float(np.percentile(gaps, 99)), "p999": float(np.percentile(gaps, 99.9)),
            "max": float(gaps.max()), "late": int((gaps >= LATE_MS).sum())}


def cost_us(costs_ns) -> dict | None:
    """The callback's cost per state: ``{"n", "p50", "p99", "max"}`` in µs (None: none)."""
    if not costs_ns:
        return None
    c = np.asarray(costs_ns, dtype=float) / 1e3
    return {"n": int(c.size), "p50": float(np.percentile(c, 50)),
            "p99": float(np.percentile(c, 99)), "max": float(c.max())}
