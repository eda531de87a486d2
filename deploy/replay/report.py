"""What ``iem replay`` reports beyond the service's summary: the recording, the link's
frame counts, the loads the gate would have written, the speed, the changes detected; and
the printed summary."""

from __future__ import annotations


def add_replay_figures(summary: dict, service, link, estimates,
                        source: dict) -> None:
    """What a replay's summary says beyond the service's: the recording (``source``), the
    link's frame counts, the gate's would-be writes, the speed (``speed``: recorded over wall
    time; ``cpu_speed``: recorded over ``replay_cpu_s``, the CPU of the replay's threads) and
    the changes detected."""
    decisions = service.gate.summary()
    for key in ("malformed", "implausible", "timing"):
        summary["frames"][key] = getattr(link.counters, key)
    for key in ("latency_us", "age_us", "checkpoints"):  # no wall-clock latency here
        summary.pop(key, None)
    recorded = estimates.t[-1] - estimates.t[0]
    wall = summary["wall_s"]
    # the replay's threads' CPU (the loop, the learning inline in it, the reader): on a
    # shared machine the wall time counts the others' work too, this does not
    cpu = summary["cpu_parts"]["cycle"] + summary["cpu_parts"]["reader"]
    summary.update({
        **source,
        "truncated": bool(getattr(link, "truncated", False)),  # the link warned (iem.bridge)
        "recorded_s": recorded,
        "writes": {"would_send": decisions["decisions"].get("send", 0), "sent": 0,
                   "rejected": decisions["rejected"],
                   "would_send_loads": [_load_record(t, load, prior)
                                        for t, load, prior in service.gate.sent_loads]},
        "estimates_per_s": summary["estimates"] / wall if wall > 0 else None,
        "speed": recorded / wall if wall > 0 else None,
        "replay_cpu_s": cpu,
        "cpu_speed": recorded / cpu if cpu > 0 else None,
        # payload changes the model detected (None: a model without a detector)
        "payload_changes": getattr(service.model, "changes", None),
    })


def _load_record(t: float, load, from_prior) -> dict:
    """A load the gate would have written, as the JSON summary lists it: controller time
    (s), mass (kg), CoM in the flange frame (m), inertia about the CoM (kg·m², ``[Ixx, Ixy,
    Ixz, Iyy, Iyz, Izz]``), and the groups its model took from the prior; the empty load
    (a removed payload cleared) is mass 0."""
    if load is None:  # the empty load
        return {"t": float(t), "mass": 0.0, "com": [0.0, 0.0, 0.0],
                "inertia": [0.0] * 6, "from_prior": list(from_prior)}
    return {"t": float(t), "mass": float(load.mass), "com": [float(v) for v in load.com],
            "inertia": [float(v) for v in load.inertia], "from_prior": list(from_prior)}


def print_summary(s: dict, log=print) -> None:
    what = f"{s['profile']} profile" if s.get("profile") else f"{s['format']} recording"
    log(f"replay of {s['log_file']} ({what}, {s['model']})"
        + (", TRUNCATED: replayed what it holds" if s.get("truncated") else "") + ":")
    log(f"  {s['estimates']} estimates over {s['recorded_s']:.3f} s of recorded time, "
        f"{s['bags']} bags; {s['wall_s']:.2f} s wall"
        + (f" ({s['estimates_per_s']:.0f} estimates per s)" if s["estimates_per_s"] else "")
        + f", {s['replay_cpu_s']:.2f} s CPU"
        + (f" ({s['cpu_speed']:.1f} times real time per CPU s)" if s["cpu_speed"] else ""))
    g = s.get("mae_groups")
    if g:
        log(f"  MAE against {s['payload']}: mass {g['mass']:.4f} kg, com {g['com']:.4f} kg·m, "
            f"inertia {g['inertia']:.5f} kg·m²")
    cov = s.get("coverage_2sigma")
    if cov and any(v is not None for v in cov.values()):
        log("  2-sigma coverage: " + ", ".join(f"{k} {v:.2f}" for k, v in cov.items()
                                               if v is not None))
    w = s["writes"]
    gate = ", ".join(f"{k} {v}" for k, v in sorted(s["gate"].items())) or "none"
    log(f"  writes: none sent (replay); the gate would have sent {w['would_send']}, rejected "
        f"{w['rejected']}; decisions: {gate}")
    for load in w.get("would_send_loads", [])[:5]:
        log(f"    t {load['t']:.3f} s: mass {load['mass']:.4f} kg, CoM "
            f"[{', '.join(f'{v:.4f}' for v in load['com'])}] m"
            + (f" ({', '.join(load['from_prior'])} from the prior)"
               if load["from_prior"] else ""))
    if s.get("arm_mismatch"):
        log(f"  WARNING: {s['arm_mismatch']['message']}")
    f = s["frames"]
    drops = ", ".join(f"{k} {v}" for k, v in f["dropped"].items()) or "none"
    log(f"  frames: {f['received']} received, dropped: {drops}, lost cycles {f['lost']}")


TABLE_COLUMNS = ("recording", "frames", "recorded s", "wall s", "speed", "mass kg",
                 "CoM mm", "error")
"""The table over many recordings (:mod:`deploy.replay.many`): per recording, the frames
received, the recorded and the wall time, the replay's speed (recorded over wall time), the
last smoothed estimate's mass and centre of mass (flange frame), and why it failed."""


def table_row(entry: dict) -> tuple[str, ...]:
    """``entry`` (a recording's entry of the many-recording JSON) as the table's cells."""
    s, phi = entry["summary"], entry["final_phi"]
    if s is None:
        return (entry["file"], *("-",) * 6, entry["error"])
    mass = phi[0]
    com = ("[" + ", ".join(f"{1000 * v / mass:.1f}" for v in phi[1:4]) + "]"
           if abs(mass) > 1e-3 else "-")  # no CoM of a massless estimate
    speed = f"{s['speed']:.1f}x" if s["speed"] else "-"
    return (entry["file"], str(s["frames"]["received"]), f"{s['recorded_s']:.2f}",
            f"{s['wall_s']:.2f}", speed, f"{mass:+.4f}", com, "")


def print_table(entries: list[dict], wall_s: float, jobs: int, log=print) -> None:
    """The table over many recordings, then the total wall time."""
    rows = [TABLE_COLUMNS, *map(table_row, entries)]
    widths = [max(len(r[j]) for r in rows) for j in range(len(TABLE_COLUMNS) - 1)]
    for row in rows:
        cells = [c.ljust(w) if j == 0 else c.rjust(w)
                 for j, (c, w) in enumerate(zip(row, widths, strict=False))]
        log("  ".join([*cells, row[-1]]).rstrip())
    failed = sum(e["error"] is not None for e in entries)
    log(f"{len(entries)} recordings, {failed} failed, in {wall_s:.2f} s wall with {jobs} "
        f"job{'s' if jobs > 1 else ''}")
