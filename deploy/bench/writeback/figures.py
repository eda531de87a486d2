"""``iem bench writeback``'s figures (``--out DIR``, the ``plots`` extra): one per scenario,
plant and seed, and one per case of the real recording.

Each shows, against controller time, the truth (what the arm carries), the smoothed estimate
with the raw estimate's 2-sigma band, and the load in force (as the controller recorded it;
for the real recording, the loads the gate would send, each taken as in force at once), each
write marked: the mass, and the CoM's z coordinate (its band ``2 sigma(m c_z) / m``, the
first moment's band over the estimated mass; drawn while the estimated mass exceeds
:data:`SHOW_COM_KG`).
"""

from __future__ import annotations

from pathlib import Path as FsPath

import numpy as np

from deploy.bench.writeback.score import at, in_force_timeline, truth_timeline

SHOW_COM_KG = 0.1
"""The CoM is drawn while the estimated mass exceeds this (a lighter one's CoM is noise)."""
COM_MARGIN_MM = 60.0
"""The CoM axis spans the truth's and the loads' CoMs, this much either side."""


def write_figures(out_dir, runs: list[dict], real: dict | None) -> list[str]:
    """Every figure, written to ``out_dir``; their file names."""
    from iem.extras import require

    require("matplotlib", "iem bench writeback's figures").use("Agg")
    import matplotlib.pyplot as plt

    out = FsPath(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    names = []
    for run in runs:
        name = f"{run['scenario']}-{run['plant']}-seed{run['seed']}" + (
            f"-part{run['part']}" if run["scenario"] == "restart" else "") + ".png"
        loads = in_force_timeline(run["initial_load"], run["controller"]["applied"])
        writes = [a["t"] for a in run["controller"]["applied"]]
        title = (f"{run['scenario']} ({run['plant']} plant, seed {run['seed']}"
                 + (f", payload {run['payload']}" if run.get("payload") else "")
                 + "): simulation")
        _figure(plt, out / name, run["t"], run["smoothed"], run["std"],
                truth_timeline(run["schedule"]), loads, writes, title, run["end_s"])
        names.append(name)
    for case, s in (real or {}).get("series", {}).items():
        name = f"real-{case}.png"
        loads = [(float(s["t"][0]), None)] + [(w["t"], w) for w in s["loads"]]
        _figure(plt, out / name, s["t"], s["smoothed"], s["std"],
                [(float(s["t"][0]), s["truth"])], loads, [w["t"] for w in s["loads"]],
                f"real recording, {case} (semi-synthetic: its exact torque added), "
                "loads the gate would send", float(s["t"][-1]))
        names.append(name)
    return names


def _figure(plt, path, t, smoothed, std, truths, loads, writes, title, end) -> None:
    fig, axes = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    t = np.asarray(t)
    grid = np.linspace(min(0.0, float(t[0])) if t.size else 0.0, end, 600)
    m = smoothed[:, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        cz = np.where(m > SHOW_COM_KG, smoothed[:, 3] / m, np.nan)
        cz_band = np.where(m > SHOW_COM_KG, 2.0 * std[:, 3] / np.abs(m), np.nan)
    series = ((axes[0], m, 2.0 * std[:, 0], "mass (kg)", _mass),
              (axes[1], 1e3 * cz, 1e3 * cz_band, "CoM z (mm)", _com_z))
    for ax, value, band, label, of in series:
        ax.fill_between(t, value - band, value + band, color="C0", alpha=0.2, lw=0,
                        label="estimate ±2σ")
        ax.plot(t, value, color="C0", lw=1, label="estimate (smoothed)")
        ax.step(grid, [of(at(truths, x)) for x in grid], where="post", color="k", lw=1.2,
                label="truth")
        ax.step(grid, [of(at(loads, x)) for x in grid], where="post", color="C3", lw=1.5,
                label="load in force")
        for w in writes:
            ax.axvline(w, color="C3", ls=":", lw=0.8)
        ax.set_ylabel(label)
    known = [_com_z(v) for _, v in [*truths, *loads]]
    known = [v for v in known if np.isfinite(v)]
    if known:  # the band of a light estimate's CoM is metres wide: keep the truth in view
        axes[1].set_ylim(min(known) - COM_MARGIN_MM, max(known) + COM_MARGIN_MM)
    axes[0].legend(fontsize=8, loc="best")
    axes[1].set_xlabel("controller time (s); dotted: each write")
    axes[0].set_title(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _mass(load) -> float:
    return 0.0 if load is None else float(load["mass"])


def _com_z(load) -> float:
    return np.nan if load is None else 1e3 * float(load["com"][2])
