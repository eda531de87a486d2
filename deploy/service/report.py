"""What a run of the service (:class:`deploy.service.loop.Service`) reports: the live status
line's text, the summary at its end (a dict: the ``stopped`` event's JSON, and what replay
and the benchmarks read) and the same summary in words, as ``iem run`` and ``iem demo``
print it.

The counters come from one value, the run's :class:`deploy.service.tally.RunTally`; the rest from
the parts that keep it: the gate (decisions, writes, the load in force), the link (frames),
the model (bags), the checkpointer.

A centre of mass is shown only where the mass is surely above zero: ``m - 2 sigma > 0``
with the raw estimate's standard deviation (``m > 0`` for a model that reports none; never
for a NaN one), the rule the gate judges the empty load by. At a mass the band does not tell
from zero (a bare flange), ``m c / m`` divides noise by noise.
"""

from __future__ import annotations

import logging
import math

import numpy as np

from deploy.writeback.checks import excludes_zero  # the gate's own rule for the empty load
from firmware_bridge.links import JointStateSource

log = logging.getLogger("iem.service")

__all__ = ["excludes_zero", "log_rate", "mass_std", "status_text", "summary_lines", "summary_of"]


def mass_std(estimate) -> float | None:
    """The standard deviation of an estimate's mass, kg: None where the model reports no
    spread (its ``std`` is None); NaN where it reports one that is not a number."""
    std = getattr(estimate, "std", None)
    if std is None:
        return None
    s = float(np.asarray(std, dtype=float).reshape(-1)[0])
    return s if s >= 0.0 else math.nan


def status_text(service, elapsed: float, record) -> str:
    """The live status line after ``elapsed`` s with the estimate of ``record`` (a
    :class:`deploy.service.loop.CycleRecord`): the smoothed mass and its 2-sigma band, the centre
    of mass where the mass is surely above zero (see the module docstring), bags, estimates
    (block points) per second, writes (sent/acked, lost, refused), the load in force and the
    gate's last verdict, drops, losses, silence."""
    c = service.link.counters
    rate = service.tally.cycles / elapsed if elapsed > 0 else 0.0
    phi, std = record.smoothed, mass_std(record.raw)
    m = float(phi[0])
    mass = f"m {m:6.3f} kg" if std is None else f"m {m:6.3f}±{2.0 * std:.3f} kg"
    if excludes_zero(m, std):
        com = phi[1:4] / m
        where = f"c [{com[0]:+.3f} {com[1]:+.3f} {com[2]:+.3f}] m"
    else:
        where = "c -"
    drops = sum(c.dropped().values())
    verdict = service.gate.verdict()
    commands = service.gate.commands
    return (f"{elapsed:6.1f} s  {mass}  {where}  bags {service.model.n_bags}  "
            f"{rate:6.0f} est/s  writes {commands.sent}/{commands.acked}"
            + (f" lost {commands.lost}" if commands.lost else "")
            + (f" refused {commands.refused}" if commands.refused else "")
            + f"  in force {_load_text(commands.load)}"
            + f"  gate {verdict['reason'] or '-'}"
            + f"  drops {drops} lost {c.lost}"
            + ("  SILENT" if service.silent else "")
            + ("  UNCHECKED: allow_without_uncertainty" if "warning" in verdict else ""))


def summary_of(service) -> dict:
    """The summary of ``service``'s last run (``iem run`` logs it, replay and the benchmarks
    read it): estimates, bags, latencies, writes, frames, learning, the gate's decisions,
    silences, checkpoints, CPU and wall time."""
    c, tally = service.link.counters, service.tally
    gate = service.gate.summary()
    return {
        "cycles": tally.cycles,
        "estimates": tally.cycles,
        "bags": service.model.n_bags,
        "model": service.model.name,
        "block_frames": service.block_frames,
        "latency_us": dict(zip(("p50", "p99"), tally.latencies.percentiles_us(50, 99),
                               strict=True)),
        "age_us": dict(zip(("p50", "p99"), tally.ages.percentiles_us(50, 99),
                           strict=True)),
        "writes": {"sent": gate["sent"], "acked": gate["acked"], "lost": gate["lost"],
                   "in_force": gate["in_force"], "rejected": gate["rejected"],
                   "refused_by_controller": gate["refused"],
                   "send_errors": gate["send_errors"], "mismatches": gate["mismatches"]},
        "load_in_force": gate["load_in_force"],
        "load_in_force_confirmed": gate["in_force_confirmed"],
        "gate_verdict": {k: v for k, v in service.gate.verdict().items()
                         if k in ("reason", "detail")},
        "frames": {"received": c.received, "dropped": c.dropped(), "lost": c.lost,
                   "skipped": tally.skipped,
                   "not_newer": service.online.skipped + (
                       0 if tally.former is None else tally.former.skipped)},
        "unlearnt": tally.unlearnt,
        "learnt": service.online.learned_points,
        "gate": gate["decisions"],
        "silences": tally.silences,
        "arm_mismatch": service.arm_watch.finding,
        "checkpoints": service.checkpoints,
        "wall_s": tally.wall_s,
        "cpu_s": tally.cpu_s,
        "cpu_parts": dict(tally.cpu_parts),
        "step_cpu_s": tally.step_cpu_s,
        "cpu_dma_latency_us": (None if service.cpu_latency is None
                               else service.cpu_latency.latency_us),
    }


def summary_lines(s: dict, title: str = "", details=()) -> list[str]:
    """The summary ``s`` (:func:`summary_of`'s) in words, as ``iem run`` and ``iem demo``
    print it: a heading (the model, then ``title``), ``details`` (e.g. the demo's errors
    against the truth), then estimates, writes, the load in force, the gate's verdict,
    frames, silences, checkpoints and time."""
    lines = [f"summary ({s['model']}{', ' + title if title else ''}):", *details]
    lat, wall = s["latency_us"], s["wall_s"]
    rate = f" ({s['estimates'] / wall:.0f} per s)" if wall > 0 else ""
    latency = (f"; block to estimate p50 {lat['p50']:.0f} µs, p99 {lat['p99']:.0f} µs"
               if lat.get("p50") is not None else "")
    lines.append(f"  bags {s['bags']}; {s['estimates']} estimates, one per block point"
                 f"{rate}{latency}")
    w = s["writes"]
    lines.append(f"  writes: {w['sent']} sent, {w['acked']} acknowledged, {w['lost']} lost, "
                 f"{w['rejected']} rejected by the gate, {w['refused_by_controller']} refused "
                 "by the controller")
    confirmed = "" if s["load_in_force"] is None or s["load_in_force_confirmed"] else (
        " (not confirmed by the controller)")
    lines.append(f"  load in force: {_load_words(s['load_in_force'])}{confirmed}")
    verdict = s["gate_verdict"]
    if verdict.get("reason"):
        lines.append(f"  the gate's last verdict: {verdict['reason']}"
                     + (f", {verdict['detail']}" if verdict.get("detail") else ""))
    f = s["frames"]
    drops = ", ".join(f"{k} {v}" for k, v in f["dropped"].items()) or "none"
    lines.append(f"  frames: {f['received']} received, dropped: {drops}, lost cycles "
                 f"{f['lost']}; {s['unlearnt']} block points estimated without learning to "
                 f"stay current, {f['skipped']} skipped")
    lines.append(f"  controller silences {s['silences']}; checkpoints {s['checkpoints']}; "
                 f"{wall:.1f} s, CPU {s['cpu_s']:.2f} s")
    if s.get("arm_mismatch"):
        lines.append(f"  the arm model: {s['arm_mismatch']['message']}")
    return lines


def _load_words(load) -> str:
    """A load record (:func:`deploy.load_state.load_record`) in words."""
    if load is None:
        return "empty"
    if isinstance(load, str):
        return load
    c = load["com"]
    return f"{load['mass']:.4f} kg, CoM [{c[0]:.4f}, {c[1]:.4f}, {c[2]:.4f}] m"


def _load_text(load) -> str:
    """The load in force, short: ``1.615 kg``, ``empty`` or ``unknown``."""
    if load is None:
        return "empty"
    if isinstance(load, str):
        return load
    return f"{load.mass:.3f} kg"


def log_rate(service) -> None:
    """Log the rate the estimator runs at, and a warning if the link reports another (a
    recording run as a link: the gap rule then bridges or drops its frames)."""
    reported = service.link.rate_hz if isinstance(service.link, JointStateSource) else None
    log.info("joint states at %g Hz, block points of %d frames: %g per s", service.rate_hz,
             service.block_frames, service.point_rate_hz,
             extra={"event": "rate", "rate_hz": service.rate_hz})
    if isinstance(reported, int | float) and not math.isclose(reported, service.rate_hz,
                                                               rel_tol=0.02):
        log.warning("the link reports %g joint states a second, the estimator runs at %g "
                    "Hz: 'iem replay' a recording, which takes its rate", reported,
                    service.rate_hz, extra={"event": "rate_mismatch"})
