"""The paper benchmark's figures (``iem bench paper``): Fig. 5 (forgetting), Fig. 6 (the
error against time on the new path), the IEM's bags at the flange and the payload change.
"""

from __future__ import annotations

import numpy as np

from iem.types import GROUPS

__all__ = ["paper_figures"]


def paper_figures(out_dir, results, runs, bench, models) -> list[tuple[str, str]]:
    """The report's figures, written to ``out_dir``: ``[(file name, title)]``."""
    from iem.extras import require

    require("matplotlib", "the benchmark report's figures").use("Agg")
    import matplotlib.pyplot as plt

    done = [_forgetting_figure(plt, out_dir, results["scenarios"]["forgetting"]),
            _new_path_figure(plt, out_dir, runs["new_path"], bench.phi),
            _bags_figure(plt, out_dir, runs, bench, models["IEM"])]
    if runs.get("payload_change"):
        done.append(_change_figure(plt, out_dir, runs["payload_change"], bench))
    return done


def _forgetting_figure(plt, out_dir, f: dict) -> tuple[str, str]:
    """Fig. 5: the excitation path's MAE before and after the new task path."""
    fig, axes = plt.subplots(1, 3, figsize=(11, 3.4))
    for ax, g in zip(axes, GROUPS, strict=True):
        names = list(f)
        x = np.arange(len(names))
        ax.bar(x - 0.2, [f[n]["before"][g] for n in names], 0.4, label="before")
        ax.bar(x + 0.2, [f[n]["after"][g] for n in names], 0.4, label="after")
        ax.set_xticks(x, names)
        ax.set_yscale("log")
        ax.set_title(f"{g} MAE on the excitation path")
    axes[0].legend()
    fig.tight_layout()
    fig.savefig(out_dir / "fig5_forgetting.png", dpi=110)
    plt.close(fig)
    return "fig5_forgetting.png", "Fig. 5: forgetting"


def _new_path_figure(plt, out_dir, new_path: dict, phi) -> tuple[str, str]:
    """Fig. 6: each model's absolute error against time on the new path."""
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6), sharex=True)
    for name, run in new_path.items():
        err = np.abs(run.smoothed - phi)
        for ax, idx in zip(axes, GROUPS.values(), strict=True):
            ax.semilogy(run.t, err[:, list(idx)].mean(axis=1) + 1e-12, label=name, lw=1)
    for ax, g in zip(axes, GROUPS, strict=True):
        ax.set_title(f"{g}: absolute error on the new path")
        ax.set_xlabel("t (s)")
    axes[0].legend()
    fig.tight_layout()
    fig.savefig(out_dir / "fig6_new_path_error.png", dpi=110)
    plt.close(fig)
    return "fig6_new_path_error.png", "Fig. 6: error against time on the new path"


def _bags_figure(plt, out_dir, runs: dict, bench, iem) -> tuple[str, str]:
    """The IEM's bags at the flange: the block points by bag, and the bags' centres."""
    fig = plt.figure(figsize=(6, 5))
    ax = fig.add_subplot(projection="3d")
    for _label, ro, run in (("excitation", bench.exc_rollout, runs["excitation"]["IEM"]),
                           ("new path", bench.new_rollout, runs["new_path"]["IEM"])):
        pts = bench.kin.flange_positions(ro.q[run.last[::2]])  # block points' last frames
        ax.scatter(*pts.T, c=run.bags[::2], cmap="tab10", s=2, vmin=0, vmax=9)
    centres = iem.router.flange_means
    ax.scatter(*centres.T, c="k", marker="x", s=60, label="bag centres")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m)")
    ax.legend()
    ax.set_title(f"{len(centres)} bags at the flange")
    fig.tight_layout()
    fig.savefig(out_dir / "bags.png", dpi=110)
    plt.close(fig)
    return "bags.png", "bags in the workspace"


def _change_figure(plt, out_dir, change_runs: dict, bench) -> tuple[str, str]:
    """The mass error against time with the payload switched at mid-path (dotted: each
    detected change)."""
    fig, ax = plt.subplots(figsize=(8, 3.6))
    for name, run in change_runs.items():
        k = int(np.searchsorted(run.last, bench.change_at))  # block points from here on
        truth = np.where(np.arange(len(run.t)) < k, bench.phi[0],
                         bench.change_payload.to_phi()[0])
        line, = ax.semilogy(run.t, np.abs(run.smoothed[:, 0] - truth) + 1e-9, lw=1,
                            label=name)
        for i in np.flatnonzero(run.changes):
            ax.axvline(run.t[i], color=line.get_color(), ls=":", lw=1)
    ax.axvline(run.t[k], color="k", lw=1, label="switch")
    ax.set_xlabel("t (s)")
    ax.set_title("mass: absolute error, payload switched at mid-path (dotted: detected)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out_dir / "payload_change.png", dpi=110)
    plt.close(fig)
    return "payload_change.png", "payload change on the new task path"
