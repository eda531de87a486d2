"""The calibrated arm's own noise: what it leaves in IEM+phys's equations, held out.

``iem calibrate`` fits the arm (:func:`sim.calibration.calibrate_segments`) and then measures
what the fitted model still leaves unexplained, in the domain where IEM+phys uses it: the
residuals ``r`` of the equations its regression forms (:class:`iem.physics.regression.
PayloadRegression` with the same block size, low-pass and rate, fed sample by sample through
the gap rule as the online loop feeds it), on traffic the fit did not see
(:func:`iem.physics.torque_noise.measure`: per joint the size, the correlation over time and the
slow drift).

The held-out traffic comes from a cross-validation by blocks: the traffic is cut into
:data:`BLOCK_S` blocks, dealt in turn to :data:`FOLDS` folds; the arm fitted on all but one
fold measures the noise on that fold's blocks (each block a stretch of its own, its filter
started afresh). The arm that is written is then fitted on everything, so its own noise
errs on the side of too large (each fold's fit saw less traffic).

The held-out blocks share the calibration motion's poses with the traffic the folds fit,
and the arm model's error on a task path goes where the calibration motion never went: the
floor under the estimates (``bias_std``) is also read on poses the calibration did not
record (:func:`pose_floor`: the spread of the folds' arms, read as payload on random
quasi-static lines across the recorded joint range), and the larger of the two is kept.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from iem.physics.torque_noise import TorqueNoise, bias_std, equations, measure, phantom_payloads
from iem.types import NOMINAL_RATE_HZ

from .arm import ArmDynamics, ArmParams
from .calibration import CalibrationError, CalibrationSettings, calibrate_segments

FOLDS = 5
"""Folds of the cross-validation."""
BLOCK_S = 2.0
"""Length of a held-out block, s."""
MIN_HELD_S = 2.0
"""Shortest held-out traffic, s, over all folds."""
POSE_LINES = 30
"""Random lines across the recorded joint range :func:`pose_floor` reads the folds' arms on."""
LINE_POSES = 30
"""Poses per line (a quasi-static motion, one equation each)."""
POSE_SEED = 0
"""Seed of the random lines."""
REGRESSION = {"cutoff_hz": 4.0, "rate_hz": NOMINAL_RATE_HZ, "update_every": 10}
"""The equations the noise is measured in: IEM+phys's defaults (its low-pass cut-off, the
joint states' rate and the block size)."""


def regression_at(rate_hz: float) -> dict:
    """:data:`REGRESSION` for joint states at ``rate_hz``: blocks of
    :func:`iem.signals.rate.block_frames_for` frames, so that the equations come at about 100
    a second, as IEM+phys's do at that rate."""
    from iem.signals.rate import block_frames_for

    return {**REGRESSION, "rate_hz": float(rate_hz), "update_every": block_frames_for(rate_hz)}


def folds(parts, n_folds: int = FOLDS, block_s: float = BLOCK_S) -> list[tuple[list, list]]:
    """``[(fitted parts, held-out parts), ...]`` per fold: each segment ``(t, q, dq, tau)`` cut
    into blocks of ``block_s`` dealt in turn to the folds (the last block takes the rest);
    a fold's fitted parts are the runs of blocks between its own."""
    out = [([], []) for _ in range(n_folds)]
    k = 0
    for t, q, dq, tau in parts:
        t = np.asarray(t, dtype=float)
        n_blocks = max(1, int((t[-1] - t[0]) // block_s))
        edges = np.searchsorted(t, t[0] + block_s * np.arange(1, n_blocks))
        bounds = list(zip(np.r_[0, edges], np.r_[edges, t.shape[0]], strict=True))
        owner = [(k + i) % n_folds for i in range(len(bounds))]
        k += len(bounds)

        def piece(a, b, t=t, q=q, dq=dq, tau=tau):
            return (t[a:b], q[a:b], dq[a:b], tau[a:b])

        for f in range(n_folds):
            run = None
            for (a, b), o in zip(bounds, owner, strict=True):
                if o == f:
                    out[f][1].append(piece(a, b))
                    if run is not None:
                        out[f][0].append(piece(*run))
                    run = None
                else:
                    run = (a, b) if run is None else (run[0], b)
            if run is not None:
                out[f][0].append(piece(*run))
    return [(fit, held) for fit, held in out if held]


def calibrate_with_noise(parts, settings: CalibrationSettings | None = None,
                         source: str = "traffic", end_effector=None,
                         description=None) -> ArmParams:
    """The arm of the arm model ``description`` (None: the default) fitted on all ``parts``,
    carrying the noise its fits measured on traffic they did not see (see the module
    docstring)."""
    from .calibration import segments

    settings = CalibrationSettings() if settings is None else settings
    held_residuals = []
    for fit, held in folds(parts):
        shortest = 4.0 * settings.trim_s + 2.0 + 0.01  # what a fit filters (prepare)
        fit = [s for p in fit for s in segments(*p, min_s=shortest)]
        partial = calibrate_segments(fit, settings, source, end_effector, refuse=False,
                                     description=description, posterior=False)
        held_residuals.append((partial, held))
    from iem.signals.rate import detect_rate

    rate = settings.recorded_rate_hz or (detect_rate(parts[0][0]) if parts else NOMINAL_RATE_HZ)
    noise = _measure_folds(held_residuals, f"{FOLDS}-fold cross-validation on {source}",
                           regression_at(rate))
    q = np.vstack([np.asarray(p[1], dtype=float) for p in parts])
    unseen = pose_floor([a for a, _ in held_residuals], q.min(axis=0), q.max(axis=0), noise)
    noise = replace(noise, bias_std=tuple(np.maximum(noise.bias_std, unseen)))
    arm = calibrate_segments(parts, settings, source, end_effector, description=description)
    report = {**arm.report, "noise": noise.to_dict()}
    return replace(arm, noise=noise.to_dict(), report=report)


def _measure_folds(pairs, source: str, c: dict = REGRESSION) -> TorqueNoise:
    """The noise the arms of ``(arm, held-out parts)`` pairs leave on their parts (each part a
    stretch of its own), pooled: the size,
    correlation and drift of the residuals (:func:`iem.physics.torque_noise.measure`), then the
    correlation weight scaled by what the phantom payloads of the held-out stretches show
    (:func:`iem.physics.torque_noise.phantom_payloads`: their spread beyond their own variances is
    the noise's ``bias_std``)."""
    from iem.physics.regression import PayloadRegression

    stretches, weight, r_tau = [], 1.0, 0.0
    for arm, held in pairs:
        dynamics = ArmDynamics(arm)
        for t, q, dq, tau in held:
            reg = PayloadRegression(dynamics, cutoff_hz=c["cutoff_hz"], rate_hz=c["rate_hz"],
                                    settle=-1, decimate=c["update_every"])
            weight, r_tau = reg.correlation_weight, reg.r_tau
            stretches += equations(reg, t, q, dq, tau, c["rate_hz"])
    rate = c["rate_hz"] / c["update_every"]
    n = sum(len(s) for s in stretches)
    if n < MIN_HELD_S * rate:
        raise CalibrationError(f"{n / rate:.1f} s of held-out equations is too little to "
                               f"measure the arm's noise on; record at least "
                               f"{FOLDS * BLOCK_S + 4:.0f} s of the calibration motion")
    e = np.array([eq[1] for s in stretches for eq in s])
    noise = measure(e, rate, weight, c["cutoff_hz"], source)
    phantoms, variances = phantom_payloads(stretches, noise, weight, r_tau)
    return replace(noise, bias_std=tuple(bias_std(phantoms, variances)))


def pose_floor(arms, q_low, q_high, noise: TorqueNoise, lines: int = POSE_LINES,
               poses: int = LINE_POSES, seed: int = POSE_SEED) -> np.ndarray:
    """What the calibration's own uncertainty reads as payload on poses it did not record
    (10: kg, kg·m, kg·m²): the delete-a-fold jackknife standard deviation of the payloads
    the fold ``arms`` (each fitted without one fold) read, relative to one another, on
    ``lines`` random straight lines between poses drawn uniformly in ``[q_low, q_high]``
    (rad, the recorded range), ``poses`` (>= 20) quasi-static poses each, weighted as IEM+phys
    weights them with ``noise`` (:func:`iem.physics.torque_noise.phantom_payloads`), its
    variance averaged over the lines.

    The folds' arms differ where the traffic left their parameters loose: least on the
    calibration motion's own poses, which their fits share, more across the range. A line
    sees gravity only: the inertia's entries come out near zero here and the held-out
    stretches' floor stands for them."""
    k = len(arms)
    if k < 2:
        return np.zeros(10)
    rng = np.random.default_rng(seed)
    dynamics = [ArmDynamics(a) for a in arms]
    zero, var = np.zeros(len(q_low)), np.zeros(10)
    for _ in range(lines):
        a, b = rng.uniform(q_low, q_high), rng.uniform(q_low, q_high)
        path = a + np.linspace(0.0, 1.0, poses)[:, None] * (b - a)
        eqs = [[] for _ in arms]
        for q in path:
            ref, Y, _ = dynamics[0](q, zero, zero)
            for i, d in enumerate(dynamics):
                eqs[i].append((Y, d(q, zero, zero)[0] - ref, np.zeros((len(q), len(q)))))
        phi = np.vstack([phantom_payloads([e], noise, 1.0, 0.0)[0] for e in eqs])
        var += (k - 1) / k * np.sum(np.square(phi - phi.mean(axis=0)), axis=0)
    return np.sqrt(var / lines)

