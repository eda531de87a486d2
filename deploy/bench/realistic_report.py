"""The markdown report of ``iem bench realistic``: the plant, the calibration's residuals, a
table per scenario and the targets against what was measured.
"""

from __future__ import annotations

import math

from iem.types import GROUPS

__all__ = ["report"]


def _f(v, digits: int = 4) -> str:
    if v is None:
        return "-"
    return f"{v:.{digits}g}" if isinstance(v, float) and math.isfinite(v) else str(v)


def report(results: dict) -> str:
    """The markdown report (tables per scenario, the calibration, the targets)."""
    lines = _plant(results) + _calibration(results)
    for name, by_model in results["scenarios"].items():
        lines += _scenario(name, by_model)
    lines += _targets(results)
    return "\n".join(lines) + "\n"


def _plant(results: dict) -> list[str]:
    """The title and the plant, sensor and path the figures are of."""
    su = results["setup"]
    return [f"# bench realistic (seed {su['seed']}{', quick' if su['quick'] else ''})", "",
            f"Plant: reality gap seed {su['gap']['seed']} (mass ±{su['gap']['mass_rel']:.0%}, "
            f"CoM ±{su['gap']['com_abs'] * 1000:g} mm, inertia ±{su['gap']['inertia_rel']:.0%}, "
            f"Gaz friction x {su['gap']['friction_factor']}, offsets σ "
            f"{su['gap']['offset_std']} N·m); sensor σ_q {su['sensor']['sigma_q']} rad, "
            f"σ_dq {su['sensor']['sigma_dq']} rad/s, σ_tau {su['sensor']['sigma_tau']} N·m; "
            f"new task path {su['new_path_s']:.0f} s. MAE is of the smoothed estimate "
            "(τ = 0.2 s EMA, as the plug-in writes it), raw beside it.", ""]


def _calibration(results: dict) -> list[str]:
    """The calibration's residuals per joint (none with a given arm file's report)."""
    su, cal = results["setup"], results["calibration"]
    rep = cal["report"]
    lines: list[str] = []
    if rep.get("rms_before"):
        lines += ["## Calibration (bare arm, calibration motion, noise seed "
                  f"{su['calibration_noise_seed']})", "",
                  f"Condition number {rep['condition_number']:.0f}, "
                  f"{rep['base_parameters']} base parameters.", "",
                  "| joint | " + " | ".join(str(j + 1) for j in range(7)) + " |",
                  "| --- |" + " --- |" * 7,
                  "| residual RMS, nominal (N·m) | "
                  + " | ".join(f"{v:.3f}" for v in rep["rms_before"]) + " |",
                  "| residual RMS, calibrated | "
                  + " | ".join(f"{v:.3f}" for v in rep["rms_after"]) + " |"]
        held = cal.get("held_out")
        if held:
            lines += [f"| held out ({held['path']}), nominal | "
                      + " | ".join(f"{v:.3f}" for v in held["rms_nominal"]) + " |",
                      "| held out, calibrated | "
                      + " | ".join(f"{v:.3f}" for v in held["rms_calibrated"]) + " |",
                      "| held out, the true arm | "
                      + " | ".join(f"{v:.3f}" for v in held["rms_true_arm"]) + " |"]
        lines.append("")
    return lines


def _scenario(name: str, by_model: dict) -> list[str]:
    """One scenario's table, a row per model."""
    lines = [f"## {name}", "",
             "| model | mass (kg) | com (kg·m) | inertia (kg·m²) | raw mass / com / "
             "inertia | 2σ coverage (all; mass, com, inertia) | false alarms |",
             "| --- | --- | --- | --- | --- | --- | --- |"]
    for model, s in by_model.items():
        if s["mae_groups"] is None:
            lines.append(f"| {model} | refused: {s.get('refused')} | | | | | |")
            continue
        g, r = s["mae_groups"], s["mae_groups_raw"]
        cg = s["coverage_2sigma_groups"]
        cov = ("-" if s["coverage_2sigma"] is None else
               f"{s['coverage_2sigma']:.2f}; " + ", ".join(f"{cg[k]:.2f}" for k in GROUPS))
        alarms = _f(s["false_alarms"])
        if "detect_s" in s:
            alarms += f" (detected after {_f(s['detect_s'], 3)} s)"
        lines.append(f"| {model} | {_f(g['mass'])} | {_f(g['com'])} | {_f(g['inertia'])} "
                     f"| {_f(r['mass'])} / {_f(r['com'])} / {_f(r['inertia'])} | {cov} "
                     f"| {alarms} |")
    lines.append("")
    return lines


def _targets(results: dict) -> list[str]:
    """Each target against what was measured."""
    lines = ["## Targets", "",
              "| scenario.model | group | target | measured | met |",
              "| --- | --- | --- | --- | --- |"]
    for key, groups in results["targets"].items():
        scenario, model = key.split(".", 1)
        s = results["scenarios"][scenario][model]
        if s["mae_groups"] is None:
            lines.append(f"| {key} | all | | refused | no |")
            continue
        for g, target in groups.items():
            v = s["mae_groups"][g]
            lines.append(f"| {key} | {g} | {target:g} | {_f(v)} | "
                         f"{'yes' if v <= target else 'no'} |")
        if scenario == "new_path" and model == "IEM+phys+cal":
            cg = s["coverage_2sigma_groups"] or {}
            for g in GROUPS:
                v = cg.get(g)
                lines.append(f"| {key} | coverage {g} | >= 0.9 | {_f(v, 3)} | "
                             f"{'yes' if v is not None and v >= 0.9 else 'no'} |")
            fa = s["false_alarms"]
            lines.append(f"| {key} | false alarms | 0 | {fa} | {'yes' if fa == 0 else 'no'} |")
    return lines
