"""What a run of the service (:class:`deploy.service.loop.Service`) reports: the live status
line's text and the summary at its end.
"""

from __future__ import annotations

import logging
import math

import numpy as np

from firmware_bridge.links import JointStateSource

log = logging.getLogger("iem.service")

__all__ = ["log_rate", "status_text", "summary_of"]


def status_text(service, elapsed: float, phi: np.ndarray) -> str:
    """The live status line after ``elapsed`` s with the smoothed estimate ``phi``: mass,
    centre of mass, bags, estimates (block points) per second, writes (sent/acked, lost,
    refused), the load in force and the gate's last verdict, drops, losses, silence."""
    c = service.link.counters
    rate = service.cycles / elapsed if elapsed > 0 else 0.0
    m = phi[0]
    com = phi[1:4] / m if m > 0 else np.full(3, np.nan)
    drops = sum(c.dropped().values())
    verdict = service.gate.verdict()
    commands = service.gate.commands
    return (f"{elapsed:6.1f} s  m {m:6.3f} kg  c [{com[0]:+.3f} {com[1]:+.3f} "
            f"{com[2]:+.3f}] m  bags {service.model.n_bags}  {rate:6.0f} est/s  writes "
            f"{commands.sent}/{commands.acked}"
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
    c = service.link.counters
    gate = service.gate.summary()
    return {
        "cycles": service.cycles,
        "estimates": service.cycles,
        "bags": service.model.n_bags,
        "model": service.model.name,
        "block_frames": service.block_frames,
        "latency_us": dict(zip(("p50", "p99"), service.latencies.percentiles_us(50, 99),
                               strict=True)),
        "age_us": dict(zip(("p50", "p99"), service.ages.percentiles_us(50, 99),
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
                   "skipped": service.skipped + service.reader_skipped,
                   "not_newer": service.online.skipped + (
                       0 if service.reader_former is None else service.reader_former.skipped)},
        "unlearnt": service.unlearnt,
        "learnt": service.online.learned_points,
        "gate": gate["decisions"],
        "silences": service.silences,
        "arm_mismatch": service.arm_watch.finding,
        "checkpoints": service.checkpoints,
        "wall_s": service.wall_s,
        "cpu_s": service.cpu_s,
        "cpu_parts": dict(service.cpu_parts),
        "step_cpu_s": service.step_cpu_s,
        "cpu_dma_latency_us": (None if service.cpu_latency is None
                               else service.cpu_latency.latency_us),
    }


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
