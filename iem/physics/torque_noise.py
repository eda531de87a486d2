"""What an arm model leaves unexplained, in the equations IEM+phys forms: the arm's own noise.

IEM+phys's equations ``r = Y phi + e`` (:mod:`iem.physics.regression`) have, on a simulated arm,
the sensor's white noise through the filter as their error. On a real arm the error is mostly
what the arm model gets wrong (link parameters, friction, sensor offsets): larger, correlated
over time, and slowly drifting. On a real Panda after calibration it is 0.05-0.25 N·m per
joint at IEM+phys's 4 Hz / 100 Hz, with autocorrelations of 0.3-0.9 at 100 ms, where the
sensor model alone says 0.01-0.02 N·m, white. :class:`TorqueNoise` describes it per joint:

- ``std``: the RMS of the equation residual (N·m): the size of one equation's error;
- ``weight``: how many consecutive equations carry the information of one independent
  equation about a constant payload (the sum of the residual's autocorrelation at the
  equations' spacing, :func:`measure`), at least the filter's own
  (:func:`iem.physics.regression.correlation_weight`);
- ``offset_std``: the size of the part that does not average out over a window of
  equations (N·m): the slow drift of the residual's mean. IEM+phys carries one torque
  offset per joint as a state with this prior standard deviation (marginalised in its
  window of equations, :class:`iem.physics.posterior.EquationWindow`), so a mean that moves with
  the arm's temperature is not read as payload;
- ``bias_std``: what the arm model's error reads as payload on bare-arm traffic
  (:func:`phantom_payloads`): a floor under the estimate's standard deviations;
- ``gain_std``: the relative error of the torque sensors' gain (-): it scales the payload's
  own torque, so its error grows with the load, stays the same for as long as the payload
  is held (it never averages out) and is invisible on a bare arm, whose calibration takes
  the gain into its link parameters. Not measured: :data:`TORQUE_GAIN_STD` unless given.
  IEM+phys carries it as a considered parameter: it widens the standard deviations by what
  that gain error would move the estimate (:class:`iem.physics.posterior.EquationWindow`),
  and leaves the estimate as it is.

``iem calibrate`` measures it on traffic its fit did not see (:func:`measure`) and stores it
in the arm file; IEM+phys uses it for its weights, its NIS, its change detector and its
standard deviations. An arm without a measured noise (the nominal, uncalibrated arm) uses
:data:`NOMINAL_ARM_NOISE`, a conservative default. numpy only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import InvalidInputError
from ..signals.gaps import GapRule

N_JOINTS = 7

MAX_LAG_S = 0.5
"""The longest lag of the autocorrelation summed into ``weight``, s: what is correlated for
longer is the slow drift, the offsets' part (:data:`OFFSET_WINDOW_S`)."""
OFFSET_WINDOW_S = 2.0
"""The offset's part: the RMS of the residual's mean over windows this long, s."""
MIN_OFFSET_STD = 0.01
"""Smallest offset standard deviation, N·m: a torque sensor's offset is never known better."""


TORQUE_GAIN_STD = 0.0115
"""Relative standard deviation of a joint torque sensor's gain error (-), per joint: a
strain-gauge sensor's gain within ±2 %, read as uniform (0.02 / √3). A bare-arm calibration
cannot see it (the gain scales the arm's own torque as its link parameters do); what it does
to a payload's estimate grows with the payload's torque. The value is the sensor tolerance
that ``iem bench realistic``'s plant draws its gains from (:mod:`sim.reality_gap`), checked
on seed 0 and reported on seeds 1-2 and ``iem bench real``."""


def _vec(name: str, value) -> tuple[float, ...]:
    a = np.asarray(value, dtype=float).reshape(-1)
    if a.shape != (N_JOINTS,) or not np.all(np.isfinite(a)) or np.any(a < 0.0):
        raise InvalidInputError(f"torque noise {name} must be {N_JOINTS} finite numbers >= 0, "
                                f"got {value!r}")
    return tuple(float(v) for v in a)


@dataclass(frozen=True)
class TorqueNoise:
    """The error of IEM+phys's equations on one arm, per joint (see the module docstring).

    Attributes:
        std: RMS of the equation residual, N·m (7).
        weight: equations per independent one (7, >= 1).
        offset_std: prior standard deviation of the slowly drifting offset, N·m (7).
        cutoff_hz: the regression's low-pass cut-off it was measured at, Hz.
        rate_hz: the equations' rate it was measured at (the block rate), Hz.
        source: where it comes from ("measured on ...", or "default").
        bias_std: the payload the arm model's error reads as, per parameter of ``phi``
            (10: kg, kg·m, kg·m²), over held-out stretches (:func:`bias_std`): a
            floor under the estimate's standard deviations that no amount of motion lowers.
        gain_std: relative standard deviation of each joint's torque-sensor gain error (7,
            -): an error of the payload's own torque, in proportion to it.
    """

    std: tuple[float, ...]
    weight: tuple[float, ...]
    offset_std: tuple[float, ...]
    cutoff_hz: float = 4.0
    rate_hz: float = 100.0
    source: str = "default"
    bias_std: tuple[float, ...] = (0.0,) * 10
    gain_std: tuple[float, ...] = (TORQUE_GAIN_STD,) * N_JOINTS

    def __post_init__(self) -> None:
        b = np.asarray(self.bias_std, dtype=float).reshape(-1)
        if b.shape != (10,) or not np.all(np.isfinite(b)) or np.any(b < 0.0):
            raise InvalidInputError(f"torque noise bias_std must be 10 finite numbers >= 0, "
                                    f"got {self.bias_std!r}")
        object.__setattr__(self, "bias_std", tuple(float(v) for v in b))
        object.__setattr__(self, "std", _vec("std", self.std))
        object.__setattr__(self, "weight", _vec("weight", self.weight))
        object.__setattr__(self, "offset_std", _vec("offset_std", self.offset_std))
        object.__setattr__(self, "gain_std", _vec("gain_std", self.gain_std))
        if max(self.gain_std) >= 0.5:
            raise InvalidInputError(f"torque noise gain_std must be < 0.5 (a relative error), "
                                    f"got {self.gain_std}")
        if min(self.weight) < 1.0:
            raise InvalidInputError(f"torque noise weight must be >= 1, got {self.weight}")

    def to_dict(self) -> dict:
        return {"std": list(self.std), "weight": list(self.weight),
                "offset_std": list(self.offset_std), "cutoff_hz": self.cutoff_hz,
                "rate_hz": self.rate_hz, "source": self.source,
                "bias_std": list(self.bias_std), "gain_std": list(self.gain_std)}

    @classmethod
    def from_dict(cls, d: dict) -> TorqueNoise:
        try:
            return cls(d["std"], d["weight"], d["offset_std"], float(d["cutoff_hz"]),
                       float(d["rate_hz"]), str(d.get("source", "")),
                       d.get("bias_std", (0.0,) * 10),
                       d.get("gain_std", (TORQUE_GAIN_STD,) * N_JOINTS))
        except (KeyError, TypeError, ValueError) as exc:
            raise InvalidInputError(f"torque noise {d!r} is not valid: {exc}") from exc


NOMINAL_ARM_NOISE = TorqueNoise(
    std=(1.0, 1.0, 0.6, 0.6, 0.3, 0.3, 0.2),
    weight=(50.0,) * N_JOINTS,
    offset_std=(0.5, 0.5, 0.3, 0.3, 0.2, 0.2, 0.1),
    source="default: the nominal, uncalibrated arm",
    bias_std=(0.1, 0.01, 0.01, 0.01, 0.005, 0.005, 0.005, 0.005, 0.005, 0.005))
"""The noise of an arm model that was not calibrated: a real Panda departs from its nominal
model by 0.5-2 N·m RMS per joint (published identifications), mostly friction and link
errors that change slowly with the motion (taken as correlated over 0.5 s at 100 Hz), and
its torque sensors carry offsets of tenths of a N·m; a few percent of link-parameter error
alone reads as about 0.1 kg of payload. With it the physics only moves the
estimate where the motion tells far more than that, and the estimate stays near the
ensemble's prior with wide standard deviations: calibrate the arm (``iem calibrate``)."""


def measure(residual: np.ndarray, rate_hz: float, filter_weight: float,
            cutoff_hz: float = 4.0, source: str = "measured") -> TorqueNoise:
    """The :class:`TorqueNoise` of the equation residuals ``residual`` (``(N, 7)``, N·m, one
    row per equation at ``rate_hz``, consecutive, a bare arm: ``r`` of the equations).

    ``std`` is the RMS about zero (a bias is error too); ``weight`` the sum over lags of
    ``|lag| <= MAX_LAG_S`` of the autocorrelation of the residual about its mean, with a
    triangular taper, at least ``filter_weight`` (a sum over lags as long as a moving mean
    that is taken out tends to zero, so the drift is not taken out here: it is short against
    :data:`OFFSET_WINDOW_S`); ``offset_std`` the RMS of the residual's
    :data:`OFFSET_WINDOW_S` moving mean, at least :data:`MIN_OFFSET_STD`.
    """
    e = np.asarray(residual, dtype=float)
    if e.ndim != 2 or e.shape[1] != N_JOINTS or e.shape[0] < 10:
        raise InvalidInputError(f"measuring the torque noise needs at least 10 equations of "
                                f"{N_JOINTS} joints, got {e.shape}")
    std = np.sqrt(np.mean(e * e, axis=0))
    n = e.shape[0]
    w = max(1, min(n, round(OFFSET_WINDOW_S * rate_hz)))
    kernel = np.ones(w) / w
    slow = np.array([np.convolve(e[:, j], kernel, mode="same") for j in range(N_JOINTS)]).T
    # the edges of 'same' average fewer samples: scale them up to a mean
    counts = np.convolve(np.ones(n), np.ones(w), mode="same") / w
    slow /= counts[:, None]
    offset = np.maximum(np.sqrt(np.mean(slow * slow, axis=0)), MIN_OFFSET_STD)
    fast = e - e.mean(axis=0)
    lags = min(n - 1, round(MAX_LAG_S * rate_hz))
    weight = np.empty(N_JOINTS)
    for j in range(N_JOINTS):
        x = fast[:, j]
        var = float(x @ x) / n
        if var <= 0.0:
            weight[j] = filter_weight
            continue
        acf = np.array([float(x[:n - k] @ x[k:]) / n / var for k in range(1, lags + 1)])
        taper = 1.0 - np.arange(1, lags + 1) / (lags + 1)
        weight[j] = max(filter_weight, 1.0 + 2.0 * float(np.sum(acf * taper)))
    return TorqueNoise(std, weight, offset, float(cutoff_hz), float(rate_hz), source)


def equations(regression, t, q, dq, tau, rate_hz: float) -> list[tuple]:
    """The equations ``(Y, r, R)`` ``regression`` (a fresh :class:`iem.physics.regression.
    PayloadRegression`) forms from a recording ``t (N,)``, ``q, dq, tau (N, 7)`` fed sample by
    sample through the gap rule at ``rate_hz`` as the online loop does, in order; a restart
    of its filter (a long gap) starts a new stretch: a list of stretches, each a list of
    equations."""
    from ..signals.gaps import RESTART, SKIP

    rule = GapRule(rate_hz)
    x = np.hstack((np.asarray(q, float), np.asarray(dq, float), np.asarray(tau, float)))
    stretches: list[list[tuple]] = [[]]
    for k, tk in enumerate(np.asarray(t, dtype=float)):
        steps = rule(float(tk))
        if steps == SKIP:
            continue
        if steps == RESTART and stretches[-1]:
            stretches.append([])
        eq = regression(x[k], None, steps)
        if eq is not None:
            stretches[-1].append(eq)
    return [s for s in stretches if s]


PHANTOM_PRIOR_STD = (3.0, 0.3, 0.3, 0.3, 0.01, 0.01, 0.01, 0.01, 0.01, 0.01)
"""Prior standard deviation of a phantom payload's parameters (kg, kg·m, kg·m²: the Panda's
rated payload, as :data:`iem.physics.posterior.DEFAULT_PRIOR_STD`)."""


def phantom_payloads(stretches: list[list[tuple]], noise: TorqueNoise, filter_weight: float,
                     r_tau: float) -> tuple[np.ndarray, np.ndarray]:
    """The payloads ``phi`` (``(S, 10)``, and their variances) that bare-arm equations
    (``stretches`` of ``(Y, r, R)``, S of them with at least 20 equations) read, weighted as
    IEM+phys weights them with ``noise``, with its torque offsets, under the prior
    :data:`PHANTOM_PRIOR_STD`: what the arm model's error reads as payload.

    The autocorrelation of the residual sees its correlation in time, but an arm model's
    error that follows the pose projects on the payload's regressor the same way all along a
    motion: it does not average out. The spread of these phantoms beyond their own variances
    is that part (:func:`bias_std`, :attr:`TorqueNoise.bias_std`)."""
    offset_prec = 1.0 / np.square(np.asarray(noise.offset_std))
    model_var = np.maximum(np.square(np.asarray(noise.std)) - r_tau, 0.0)
    info_var = model_var * np.maximum(np.asarray(noise.weight) / filter_weight, 1.0)
    prior_prec = 1.0 / np.square(PHANTOM_PRIOR_STD)
    est, var = [], []
    for stretch in stretches:
        if len(stretch) < 20:
            continue
        A = np.zeros((17, 17))
        b = np.zeros(17)
        for Y, r, R in stretch:
            Ya = np.hstack((Y, np.eye(N_JOINTS)))
            Ri = R.copy()  # as IEM+phys's window counts it (iem.physics)
            Ri[np.diag_indices(N_JOINTS)] += info_var
            W = np.linalg.inv(filter_weight * Ri)
            A += Ya.T @ W @ Ya
            b += Ya.T @ W @ r
        A[:10, :10] += np.diag(prior_prec)
        A[10:, 10:] += np.diag(offset_prec)
        cov = np.linalg.inv(0.5 * (A + A.T))
        est.append((cov @ b)[:10])
        var.append(np.diag(cov)[:10])
    return np.array(est).reshape(-1, 10), np.array(var).reshape(-1, 10)


def bias_std(phantoms: np.ndarray, variances: np.ndarray) -> np.ndarray:
    """The part of the phantom payloads' spread that their own standard deviations do not
    explain, at the upper end of what ``n`` phantoms can tell: per parameter
    ``sqrt(max(0, mean(phi²) - mean(var)) + sqrt(2 / n) mean(var))``; what the arm model's
    error, not the noise of a short stretch, reads as payload.

    ``sqrt(2 / n) mean(var)`` is the standard error of ``mean(phi²)`` for unbiased
    phantoms: a bias smaller than that cannot be told from the stretches' noise, and the
    arm's error on another motion (a task path the calibration never saw) projects onto
    the payload differently, so a bias hidden in it is counted, not taken as zero."""
    n = phantoms.shape[0]
    if not n:
        return np.zeros(10)
    var = np.mean(variances, axis=0)
    excess = np.mean(np.square(phantoms), axis=0) - var
    return np.sqrt(np.maximum(excess, 0.0) + math.sqrt(2.0 / n) * var)
