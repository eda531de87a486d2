"""What a run of the service (:class:`deploy.service.Service`) reports: the live status
line's text and the summary at its end.
"""

from __future__ import annotations

import numpy as np

__all__ = ["status_text", "summary_of"]


def status_text(service, elapsed: float, phi: np.ndarray) -> str:
    """The live status line after ``elapsed`` s with the smoothed estimate ``phi``: mass,
    centre of mass, bags, estimates per second, writes, refusals, drops, losses, silence."""
    c = service.link.counters
    rate = service.cycles / elapsed if elapsed > 0 else 0.0
    m = phi[0]
    com = phi[1:4] / m if m > 0 else np.full(3, np.nan)
    drops = sum(c.dropped().values())
    return (f"{elapsed:6.1f} s  m {m:6.3f} kg  c [{com[0]:+.3f} {com[1]:+.3f} "
            f"{com[2]:+.3f}] m  bags {service.model.n_bags}  {rate:6.0f} est/s  writes "
            f"{service.gate.sent}/{service.gate.acked}"
            + (f" refused {service.gate.refusals}" if service.gate.refusals else "")
            + f"  drops {drops} lost {c.lost}"
            + ("  SILENT" if service.silent else ""))


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
        "block_frames": service.config.estimate.block_frames,
        "latency_us": dict(zip(("p50", "p99"), service.latencies.percentiles_us(50, 99),
                               strict=True)),
        "age_us": dict(zip(("p50", "p99"), service.ages.percentiles_us(50, 99),
                           strict=True)),
        "writes": {"sent": gate["sent"], "acked": gate["acked"],
                   "rejected": gate["rejected"], "refused_by_controller": service.gate.refusals,
                   "send_errors": service.gate.send_errors},
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
        "cpu_dma_latency_us": (None if service.cpu_latency is None
                               else service.cpu_latency.latency_us),
    }
