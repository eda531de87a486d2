"""The torque sensors' gain, measured with a known load (``iem calibrate --known-load``).

A bare arm cannot show its torque sensors' gain error: the calibration fits the bare arm's
torque as the sensors read it. A payload's torque ``Y phi`` is read as ``(1 + g) Y phi``, so
on a heavy payload a gain of 1 % is 1 % of its mass (0.017-0.029 kg on a 2.7 kg tool on the
realistic plant). With a payload whose parameters are known (a test weight, a tool measured
on a scale and in CAD) mounted, the calibrated arm leaves, per joint ``j`` and sample::

    tau_j - tau_arm_j = (1 + g_j) (Y phi)_j + o_j + e

(``o_j`` a constant offset the load may shift). :func:`fit_gain` takes the recording through
the calibration's signal chain (:func:`.signals.calibration_signals`) and fits ``g_j`` and
``o_j`` by least squares per joint. A joint the load barely turns (its torque's RMS under
:data:`MIN_LOAD_TORQUE`, or the fit's standard deviation over :data:`MAX_GAIN_STD`) keeps no
gain and is named: joints 1 and 7 carry little of a payload's weight, and their gain is
what the load's leftover friction and the arm's leftover read.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from iem.errors import InvalidInputError

from .prior import DEFAULT_SETTINGS, CalibrationSettings
from .signals import calibration_signals

MIN_LOAD_TORQUE = 1.0
"""RMS (N·m) of the known load's torque on a joint below which its gain is not fitted."""
MAX_GAIN_STD = 0.005
"""Standard deviation of a fitted gain above which it is not kept."""


def fit_gain(arm, parts, payload, settings: CalibrationSettings = DEFAULT_SETTINGS
             ) -> tuple[np.ndarray, dict]:
    """``(gain (7,), report)``: each torque sensor's relative gain error read from the
    recordings ``parts`` (``[(t, q, dq, tau), ...]``) of the arm ``arm`` (a calibrated
    :class:`sim.arm.ArmParams`, its own gain not applied) carrying the known ``payload``
    (:class:`sim.payload.Payload`). ``report``: the payload's name, the samples, the load's
    torque RMS per joint, the joints whose gain was read (``measured``, 1-based) with the
    fit's standard deviation and the residual RMS after for each, and the joints left
    without a gain (``unmeasured``). The standard deviation is the fit's own, as if the
    residual were white: what the arm's leftover and a load's friction add is not in it.

    Raises:
        InvalidInputError: no payload, or the load turns no joint enough to read a gain.
        sim.calibration.CalibrationError: a recording the signal chain cannot use.
    """
    from sim.identify.fit import residuals_and_regressor
    from sim.robot import ArmModel

    if payload is None or not payload.mass > 0.0:
        raise InvalidInputError("a known load needs a payload with a mass > 0 kg")
    signals = calibration_signals(parts, settings)
    model = ArmModel(arm=replace(arm, gain=None))  # the arm as the sensors read it bare
    phi = payload.to_phi()
    fits = [residuals_and_regressor(model, p.q, p.dq, p.ddq, p.tau) for p in signals]
    residual = np.concatenate([r for r, _ in fits])
    load = np.concatenate([Y for _, Y in fits]) @ phi
    n = residual.shape[0]
    gain, std, after = np.zeros(7), np.full(7, np.inf), np.zeros(7)
    rms = np.sqrt(np.mean(load ** 2, axis=0))
    unmeasured = []
    for j in range(7):
        A = np.column_stack((load[:, j], np.ones(n)))
        b = residual[:, j] - load[:, j]
        if rms[j] >= MIN_LOAD_TORQUE:
            x, *_ = np.linalg.lstsq(A, b, rcond=None)
            e = b - A @ x
            var = float(e @ e) / max(n - 2, 1)
            std[j] = float(np.sqrt(var * np.linalg.inv(A.T @ A)[0, 0]))
            after[j] = float(np.sqrt(np.mean(e ** 2)))
            if std[j] <= MAX_GAIN_STD:
                gain[j] = float(x[0])
                continue
        unmeasured.append(j + 1)
    if len(unmeasured) == 7:
        raise InvalidInputError(f"the known load {payload.name!r} turns no joint by "
                                f"{MIN_LOAD_TORQUE:g} N·m RMS or more along this motion "
                                f"(at most {rms.max():.2f}): no gain to read; record the "
                                f"calibration motion with it mounted")
    measured = [j + 1 for j in range(7) if j + 1 not in unmeasured]
    report = {"payload": payload.name, "samples": n, "load_torque_rms": rms.tolist(),
              "measured": measured, "gain_std": [float(std[j - 1]) for j in measured],
              "residual_rms_after": [float(after[j - 1]) for j in measured],
              "unmeasured": unmeasured}
    return gain, report


def with_gain(arm, parts, payload, settings: CalibrationSettings = DEFAULT_SETTINGS):
    """``arm`` (:class:`sim.arm.ArmParams`) with its torque sensors' gain read by
    :func:`fit_gain` from ``parts`` with the known ``payload`` mounted; the fit's report is
    its report's ``gain``."""
    gain, report = fit_gain(arm, parts, payload, settings)
    return replace(arm, gain=gain, report={**arm.report, "gain": report})
