"""``iem bench fci``'s figures (``--out DIR``, the ``plots`` extra): one per run (way).

Each shows, against the robot's time: the truth (what the arm carries), the smoothed
estimate's mass with the raw estimate's 2-sigma band, and the load in force (``m_load``, as
the robot applied it), each ``setLoad`` marked and each refusal ticked; the motions shaded.
"""

from __future__ import annotations

from pathlib import Path as FsPath

import numpy as np

from deploy.bench.fci.score import timelines


def write_figure(path, run: dict, title: str) -> str:
    """The figure of ``run`` (``{"events", "rows", "end_s"}``) at ``path``; its name."""
    from iem.extras import require

    require("matplotlib", "iem bench fci's figures").use("Agg")
    import matplotlib.pyplot as plt

    tl = timelines(run["events"])
    end = float(run["end_s"])
    fig, ax = plt.subplots(figsize=(10, 4.5))
    for a, b in tl["motions"]:
        ax.axvspan(a, b, color="0.92", lw=0)
    rows = np.asarray(run["rows"], dtype=float).reshape(-1, 9)
    if rows.size:
        t, m, sd = rows[:, 0], rows[:, 1], rows[:, 5]
        ax.fill_between(t, m - 2 * sd, m + 2 * sd, color="tab:blue", alpha=0.2, lw=0,
                        label="2-sigma band")
        ax.plot(t, m, color="tab:blue", lw=1, label="estimate (smoothed)")
    for series, colour, label in ((tl["truth"], "k", "truth"),
                                  (tl["in_force"], "tab:red", "load in force (m_load)")):
        ts = [t for t, _ in series] + [end]
        ms = [0.0 if v is None else v["mass"] for _, v in series]
        ax.step(ts, ms + ms[-1:], where="post", color=colour, lw=1.5 if colour == "k" else 1.2,
                label=label)
    for a in tl["applied"]:
        ax.plot(a["t"], a["mass"], "v", color="tab:red", ms=5)
    if tl["refused"]:
        ax.plot(tl["refused"], np.full(len(tl["refused"]), -0.15), "|", color="tab:orange",
                ms=8, label="setLoad refused")
    top = max([0.0] + [v["mass"] for _, v in tl["truth"] + tl["in_force"] if v is not None])
    ax.set_xlim(0, end)
    ax.set_ylim(-0.4, top + 0.8)  # an estimate's jump at a change may leave the frame
    ax.set_xlabel("robot time (s); shaded: motions")
    ax.set_ylabel("mass (kg)")
    ax.set_title(title, fontsize=10)
    ax.legend(loc="upper left", fontsize=8, ncol=3)
    fig.tight_layout()
    FsPath(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return FsPath(path).name
