"""The payload regression: measured joint signals in, linear equations in phi out.

With the robot's own model the torque the payload adds is linear in its parameters,
``r = tau - tau_robot(q, dq, ddq) = Y(q, dq, ddq) phi + e``. :class:`PayloadRegression` turns
the measured ``x = [q, dq, tau]`` of each cycle into such equations ``(Y, r, R)``, with ``R``
the covariance of ``e``; the least-squares estimators (:mod:`iem.baselines.least_squares`,
:mod:`iem.physics`) only combine them.

Signals: ``q``, ``dq`` and ``tau`` go through the same causal 2nd-order Butterworth low-pass
(:class:`iem.signals.filters.LowPass2`), and ``ddq`` is the backward difference of the filtered
``dq``, so every term carries the same filter lag. An equation is given every ``every``
samples. The equation error has two parts: the filtered torque noise (``sigma_tau² g_tau``,
``g_tau`` the filter's noise gain) and the velocity noise that the differentiation turns into
``ddq`` noise, which the inertia of what moves turns into torque (errors in variables:
``M diag(sigma_ddq²) M^T``, ``sigma_ddq`` from ``sigma_dq`` and the filtered
differentiator's gain). ``M`` is the arm's mass matrix, plus, if asked (``payload_inertia``),
the payload's share ``M_p(q, phi)`` for the phi the caller passes: the payload is part of what
moves (with a 1.6 kg payload it is 10-30 % of ``M`` on the distal joints, and without it the
whitened residual of a 5 Hz regression is 25 % too large).

Start-up: the filter starts in steady state at its first sample, so that sample's noise sits
in the filtered signals and decays with the filter's step response. With ``settle`` the first
equations are withheld until it has decayed (:func:`settle_samples`).

The robot model is given by the caller, the core names none; it is named, not passed, so
that estimators stay plain data for persistence (a model file stores the name it was given):
``dynamics`` is a spec of :data:`iem.factories.FACTORIES` (``"module:function[@ARG]"``), a
factory returning ``f(q, dq, ddq) -> (tau_robot (7,), Y (7, 10), M (7, 7))`` (optionally
with a method ``payload_mass_matrix(q, phi)``, else the payload's share is taken from
``Y``), built only when the first equation is formed; the nominal arm of the default arm
model is ``sim.arm.NOMINAL_DYNAMICS``, a calibrated arm or another arm model's
``"sim.arm:arm_dynamics@arm:CRC32"`` (the arm given at run time, :mod:`iem.factories`).
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import InvalidInputError
from ..factories import build, parse, valid_specs
from ..sensor import DEFAULT_SENSOR
from ..signals.filters import LowPass2, butterworth2
from ..signals.gaps import RESTART, SKIP
from ..types import NOMINAL_RATE_HZ


def impulse_response(cutoff_hz: float, rate_hz: float, n: int = 4000) -> np.ndarray:
    """The first ``n`` samples of the low-pass's impulse response."""
    b, a = butterworth2(cutoff_hz, rate_hz)
    h = np.zeros(n)
    z1 = z2 = 0.0
    for i in range(n):
        x = 1.0 if i == 0 else 0.0
        y = b[0] * x + z1
        z1 = b[1] * x - a[1] * y + z2
        z2 = b[2] * x - a[2] * y
        h[i] = y
    return h


def noise_gains(cutoff_hz: float, rate_hz: float) -> tuple[float, float]:
    """Variance gains for white noise of the low-pass and of the filtered differentiator
    (``rate * (y_k - y_{k-1})``), so ``var(out) = gain * var(in)``."""
    h = impulse_response(cutoff_hz, rate_hz)
    dh = np.diff(np.concatenate(([0.0], h))) * rate_hz
    return float((h * h).sum()), float((dh * dh).sum())


def settle_samples(cutoff_hz: float, rate_hz: float, tol: float = 0.1) -> int:
    """Samples after a steady-state start until the first sample's noise is small.

    Started at ``x0 = s0 + n0``, the filtered output at sample ``k`` (0 the first) carries
    ``n0 (1 - step_k)`` and its difference ``-n0 rate h_k``. This is the first ``k`` from
    which both stay below ``tol`` times the steady filtered noise (standard deviations).
    """
    n = int(40 * rate_hz / cutoff_hz) + 10
    h = impulse_response(cutoff_hz, rate_hz, n)
    gain, dgain = noise_gains(cutoff_hz, rate_hz)
    tail = np.abs(1.0 - np.cumsum(h))  # weight of n0 in the output at sample k
    dtail = np.abs(h) * rate_hz  # and in the difference at sample k
    bad = np.flatnonzero((tail > tol * math.sqrt(gain)) | (dtail > tol * math.sqrt(dgain)))
    return int(bad[-1] + 1) if bad.size else 0


def correlation_weight(cutoff_hz: float, rate_hz: float, every: int = 1) -> float:
    """``sum_j rho(j * every)`` over all integers ``j``: ``rho`` the autocorrelation of white
    noise through the low-pass (normalised to 1 at lag 0). The mean of ``N`` equations
    spaced ``every`` filter samples apart has the variance of ``N / weight`` independent
    ones (for ``N`` much longer than the correlation), so each is counted as ``1 / weight``
    of one. At least 1."""
    n = int(60 * rate_hz / cutoff_hz) + 10
    h = impulse_response(cutoff_hz, rate_hz, n)
    spectrum = np.fft.rfft(h, 2 * n)
    acf = np.fft.irfft(spectrum * np.conj(spectrum), 2 * n)[:n]
    acf /= acf[0]
    return max(1.0, float(acf[0] + 2.0 * acf[every::every].sum()))


def required_dynamics(dynamics, who: str):
    """``dynamics`` if it names a robot model (a spec of :data:`iem.factories.FACTORIES`, or
    the dynamics callable itself); ``who`` names the estimator in the error.

    Raises:
        InvalidInputError: it is None, or a spec the table does not hold (nothing is
            imported for it).
    """
    if callable(dynamics):
        return dynamics
    if isinstance(dynamics, str):
        try:
            parse(dynamics, "dynamics")
        except InvalidInputError as exc:
            raise InvalidInputError(f"{who} needs dynamics, the robot's model: {exc}") from exc
        return dynamics
    raise InvalidInputError(f"{who} needs dynamics, the robot's model: the spec of its factory "
                            f"(the default arm model's nominal arm is "
                            f"sim.arm.NOMINAL_DYNAMICS; valid are {valid_specs()}) or the "
                            f"dynamics callable; got {dynamics!r}")


def load_dynamics(spec: str):
    """The dynamics callable of ``spec`` (:func:`iem.factories.build`): e.g.
    ``"sim.arm:arm_dynamics@arm:CRC32"``, the calibrated arm given at run time."""
    return build(spec, "dynamics")


class PayloadRegression:
    """Equations ``r = Y phi + e``, ``e ~ N(0, R)``, from the measured signals.

    Args:
        dynamics: the robot model (required): ``"module:function[@ARG]"`` of its factory
            (see module docstring), or the dynamics callable.
        sigma_tau: torque noise of the measurements, N·m.
        sigma_dq: velocity noise of the measurements, rad/s.
        cutoff_hz: low-pass cut-off for q, dq and tau, Hz.
        rate_hz: sample rate, Hz.
        every: give an equation every this many filter samples (>= 1).
        settle: withhold the equations of the first this many filter samples after a start
            (-1: :func:`settle_samples` of the unaveraged samples, in blocks).
        payload_inertia: add the payload's share of the mass matrix (for the ``phi`` passed
            to :meth:`__call__`) to the errors-in-variables term.
        decimate: average this many samples into one before the low-pass, which then runs
            at ``rate_hz / decimate`` (1: every sample is filtered). The mean of a block is
            a low-pass itself (first null at the block rate), so a cut-off far below the
            block rate loses nothing, and each sample costs one addition; the block means
            of white noise are white, with ``1 / decimate`` of its variance.
        model_error_std: the RMS per joint (7, N·m) of what the arm model leaves in the
            equations (:attr:`iem.physics.torque_noise.TorqueNoise.std`, measured in this domain),
            or None: the sensor noise alone. Its excess over the filtered torque noise is
            added to ``R``'s diagonal (:attr:`model_var`).
        considered: with each equation, :attr:`sensitivity`: how the arm model's torques
            move per unit of its considered parameters, if the dynamics callable has any
            (its ``considered`` count and ``sensitivity(q, dq, ddq)``, e.g.
            :class:`sim.arm.ArmDynamics` of a calibrated arm: its calibration's
            uncertainty).
    """

    def __init__(self, dynamics=None,
                 sigma_tau: float = DEFAULT_SENSOR.sigma_tau,
                 sigma_dq: float = DEFAULT_SENSOR.sigma_dq, cutoff_hz: float = 20.0,
                 rate_hz: float = NOMINAL_RATE_HZ,
                 every: int = 1, settle: int = 0, payload_inertia: bool = False,
                 decimate: int = 1, model_error_std=None, considered: bool = False) -> None:
        if int(every) < 1 or int(decimate) < 1:
            raise InvalidInputError(f"every and decimate must be >= 1 sample, got {every}, "
                                    f"{decimate}")
        self.dynamics = required_dynamics(dynamics, "PayloadRegression")
        self.sigma_tau = float(sigma_tau)
        self.sigma_dq = float(sigma_dq)
        self.cutoff_hz = float(cutoff_hz)
        self.rate_hz = float(rate_hz)
        self.every = int(every)
        self.decimate = int(decimate)
        self.filter_rate_hz = self.rate_hz / self.decimate
        """The rate the low-pass runs at, Hz."""
        # settling: the time the unaveraged filter needs (its single first sample's noise),
        # so that averaging blocks does not move the first equation earlier
        self.settle = (-(-settle_samples(cutoff_hz, rate_hz) // self.decimate) if settle < 0
                       else int(settle))
        self.payload_inertia = bool(payload_inertia)
        gain, dgain = noise_gains(cutoff_hz, self.filter_rate_hz)
        self.r_tau = self.sigma_tau ** 2 / self.decimate * gain
        """Variance of the filtered torque noise, (N·m)²."""
        self.var_ddq = self.sigma_dq ** 2 / self.decimate * dgain
        """Variance of the ``ddq`` noise, (rad/s²)²."""
        self.correlation = self.filter_rate_hz / (2.0 * cutoff_hz)
        """Filter samples over which the filtered noise stays correlated (``rate / 2 fc``)."""
        self.correlation_weight = correlation_weight(cutoff_hz, self.filter_rate_hz,
                                                     self.every)
        self.model_var = (np.zeros(7) if model_error_std is None else np.maximum(
            np.square(np.asarray(model_error_std, dtype=float).reshape(7)) - self.r_tau, 0.0))
        """Variance per joint that the arm model's error adds to ``R``'s diagonal, (N·m)²."""
        self._r_diag = self.r_tau + self.model_var
        self.considered = bool(considered)
        """How many of the equations, one every ``every`` filter samples, carry the
        information of one independent equation about a constant: the sum of the filtered
        noise's autocorrelation at multiples of that spacing (:func:`correlation_weight`)."""
        self._f = None
        self.reset()

    def reset(self) -> None:
        """Restart the filter (the next sample is a new start)."""
        self._lp = LowPass2(self.cutoff_hz, self.filter_rate_hz, channels=21)
        self.count = 0
        self._acc = np.zeros(21)  # the block being averaged (decimate > 1)
        self._n_acc = 0
        self._x: np.ndarray | None = None  # the last input sample (block averaging)
        self._robot_torques: list[np.ndarray] = []  # tau_robot of the last two equations
        self.sensitivity: np.ndarray | None = None
        """How the arm model's torques at the last equation's state move per unit of its
        considered parameters (7 x k), or None (none asked for, or none there)."""
        self.curvature: np.ndarray | None = None
        """Second difference of the robot model's torque ``tau_robot`` over the last three
        equations (7, N·m), None until three consecutive equations since the start: how
        sharply the arm's own torque bends, which sets the error of the filtered equations
        (:data:`iem.physics.innovation.MODEL_ERROR_GAIN`)."""

    @property
    def r_diag(self) -> np.ndarray:
        """The diagonal of ``R`` without the velocity noise's share: the filtered torque
        noise plus the arm model's error, (N·m)² per joint (read-only view)."""
        return self._r_diag

    @property
    def settled(self) -> bool:
        """True once the start's noise has decayed (equations are being given)."""
        return self.count > self.settle

    def model(self):
        """The dynamics callable (loaded on first use; ``dynamics`` may be the callable
        itself instead of its spec)."""
        if self._f is None:
            self._f = (load_dynamics(self.dynamics) if isinstance(self.dynamics, str)
                       else self.dynamics)
        return self._f

    def payload_mass_matrix(self, q, dq, ddq, Y, phi) -> np.ndarray:
        """The payload's share of the mass matrix, ``M_p = d(Y phi)/d ddq`` (7x7).

        ``Y = Y(q, dq, ddq)`` is linear in ``ddq``, so column ``i`` is
        ``(Y(q, dq, ddq + e_i) - Y) phi``; a dynamics callable with a
        ``payload_mass_matrix(q, phi)`` method gives it directly instead.
        """
        f = self.model()
        direct = getattr(f, "payload_mass_matrix", None)
        if direct is not None:
            return np.asarray(direct(q, phi), dtype=float)
        base = Y @ phi
        out = np.empty((7, 7))
        step = np.array(ddq, dtype=float)
        for i in range(7):
            step[i] += 1.0
            out[:, i] = f(q, dq, step)[1] @ phi - base
            step[i] -= 1.0
        return out

    def __call__(self, x, phi=None, steps: int = 1):
        """Take one sample; when an equation is due (every ``every``-th filter sample after
        settling), return ``(Y, r, R)``.

        ``steps`` is the gap rule's verdict on the sample (:mod:`iem.signals.gaps`): the nominal
        cycles since the last sample (the lost ones are bridged: linearly interpolated
        inputs, so ``ddq`` is always a difference over one filter sample), ``RESTART`` (the
        filter starts again here) or ``SKIP`` (not used, no equation). Returns None when no
        equation is due. ``phi`` (10, or a zero-argument callable giving it, called only
        when an equation is formed) is the payload used for its share of the mass matrix if
        ``payload_inertia`` (ignored if it is or gives None).
        """
        if steps == SKIP:
            return None
        if steps == RESTART:
            self.reset()
            steps = 1
        x = np.asarray(x, dtype=float)
        if self.decimate == 1:  # the filter bridges the gap itself
            return self._filter(x, steps, phi)
        if steps > 1 and self._x is not None:  # bridge: the lost samples, interpolated
            x0 = self._x
            for j in range(1, steps):
                self._push(x0 + (x - x0) * (j / steps), None, form=False)
        self._x = x
        return self._push(x, phi)

    def _push(self, x: np.ndarray, phi, form: bool = True):
        """Add a sample to the block; filter the block's mean when it is full."""
        self._acc += x
        self._n_acc += 1
        if self._n_acc < self.decimate:
            return None
        mean = self._acc / self.decimate
        self._acc[:] = 0.0
        self._n_acc = 0
        return self._filter(mean, 1, phi, form)

    def _filter(self, x: np.ndarray, steps: int, phi, form: bool = True):
        f = self._lp(x, steps)
        before = self.count
        self.count += steps
        prev = self._lp.previous
        if (not form or prev is None or self.count // self.every == before // self.every
                or self.count <= self.settle):
            return None
        # ddq is the difference over the last filter sample: it belongs to the instant half
        # a sample back, so q, dq and tau are taken there too (at 100 Hz a 5 ms mismatch
        # otherwise reads the arm's jerk as payload inertia)
        mid = 0.5 * (f + prev)
        q, dq, tau = mid[:7], mid[7:14], mid[14:]
        ddq = (f[7:14] - prev[7:14]) * self.filter_rate_hz
        f = self.model()
        tau_robot, Y, M = f(q, dq, ddq)
        if self.considered and getattr(f, "considered", 0):
            self.sensitivity = f.sensitivity(q, dq, ddq)
        last = self._robot_torques
        self.curvature = tau_robot - 2.0 * last[1] + last[0] if len(last) == 2 else None
        last.append(tau_robot)
        if len(last) > 2:
            del last[0]
        if self.payload_inertia and callable(phi):
            phi = phi()
        if self.payload_inertia and phi is not None:
            M = M + self.payload_mass_matrix(q, dq, ddq, Y, np.asarray(phi, dtype=float))
        R = self.var_ddq * (M @ M.T)
        R.flat[::8] += self._r_diag  # the diagonal
        return Y, tau - tau_robot, R

    # -- persistence ---------------------------------------------------------------------
    def to_state(self) -> dict:
        lp = self._lp

        def vec(v):
            return None if v is None else v.tolist()

        return {"count": self.count,
                "filter": None if not lp._started else [z.tolist() for z in lp.state],
                "input": vec(lp._x), "output": vec(lp._y), "previous": vec(lp.previous),
                "block": [self._acc.tolist(), self._n_acc], "last": vec(self._x)}

    def set_state(self, state: dict) -> None:
        """What :meth:`to_state` gave (of a file: as :mod:`iem.migrations` brings it)."""
        self.reset()
        self.count = int(state["count"])
        if state["filter"] is not None:
            lp = self._lp
            lp.state = [np.array(v, dtype=float) for v in state["filter"]]
            lp._started = True
            for key, attr in (("input", "_x"), ("output", "_y"), ("previous", "previous")):
                value = state[key]
                setattr(lp, attr, None if value is None else np.array(value, dtype=float))
        acc, n_acc = state["block"]
        self._acc = np.array(acc, dtype=float).reshape(21)
        self._n_acc = int(n_acc)
        if state["last"] is not None:
            self._x = np.array(state["last"], dtype=float).reshape(21)
