"""LS: classical recursive least squares on the payload regressor (the physics anchor).

What a robotics engineer would pick instead of learning: with the robot's own model, the
torque the payload adds is linear in its parameters, ``tau - tau_robot(q, dq, ddq) =
Y(q, dq, ddq) phi``. Recursive least squares (in Kalman form, 7 equations per update):

    S = Y P Y^T + R,  K = P Y^T S^-1,  phi <- phi + K (r - Y phi),  P <- P - K S K^T

Signals: ``q``, ``dq`` and ``tau`` go through the same causal 2nd-order Butterworth low-pass
(default 20 Hz), and ``ddq`` is the backward difference of the filtered ``dq``, so every
term carries the same filter lag. The filtered torque noise is correlated over about
``rate / (2 cutoff)`` samples, so the filter updates only every ``decimate`` samples
(default: that correlation length). The equation error has two parts: the filtered torque
noise (``sigma_tau² g_tau``, ``g_tau`` the filter's noise gain) and the velocity noise that
the differentiation turns into ``ddq`` noise, which the arm's own inertia turns into torque
(errors in variables: ``M(q) diag(sigma_ddq²) M(q)^T``, ``sigma_ddq`` from ``sigma_dq`` and
the filtered differentiator's gain). ``R`` is their sum, so the reported uncertainty
``std = sqrt(diag(P))`` stays honest. The prior is zero with a standard deviation sized to
the Panda's rated payload (3 kg, CoM within 0.1 m, inertia within 0.01 kg·m²): the
classical method knows the robot's rating, not the payload family.

The robot model is named, not passed, so that the model stays plain data for persistence:
``dynamics = "module:function"`` names a factory returning ``f(q, dq, ddq) -> (tau_robot (7,),
Y (7, 10), M (7, 7))``; the default is the nominal Panda of :mod:`sim.robot` (imported only
when the model first learns).
"""

from __future__ import annotations

import importlib

import numpy as np

from .base import Samples
from .errors import InvalidInputError
from .filters import LowPass2, butterworth2
from .types import PayloadEstimate

DEFAULT_PRIOR_STD = (3.0, 0.3, 0.3, 0.3, 0.01, 0.01, 0.01, 0.01, 0.01, 0.01)
"""Prior standard deviation per parameter (kg, kg·m, kg·m²): the Panda's rated payload."""


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


def load_dynamics(spec: str):
    """Resolve ``"module:function"`` and call the factory: the dynamics callable."""
    try:
        module, _, attr = spec.partition(":")
        return getattr(importlib.import_module(module), attr)()
    except (ImportError, AttributeError, ValueError) as exc:
        raise InvalidInputError(f"dynamics {spec!r} is not 'module:function' naming a "
                                f"factory: {exc}") from exc


class RecursiveLeastSquares:
    """Recursive least squares on the payload regressor.

    Args:
        dynamics: ``"module:function"`` of the robot-model factory (see module docstring).
        sigma_tau: torque noise of the measurements, N·m.
        cutoff_hz: low-pass cut-off for q, dq and tau, Hz.
        rate_hz: sample rate, Hz.
        decimate: update every this many samples (0: the noise correlation length).
        prior_std: prior standard deviation per parameter (10 values).
    """

    name = "LS"

    def __init__(self, dynamics: str = "sim.robot:panda_dynamics", sigma_tau: float = 0.05,
                 sigma_dq: float = 2e-3, cutoff_hz: float = 20.0, rate_hz: float = 1000.0,
                 decimate: int = 0, prior_std=DEFAULT_PRIOR_STD) -> None:
        self.dynamics = dynamics
        self.sigma_tau = float(sigma_tau)
        self.sigma_dq = float(sigma_dq)
        self.cutoff_hz = float(cutoff_hz)
        self.rate_hz = float(rate_hz)
        self.decimate = int(decimate)
        self.prior_std = tuple(float(v) for v in prior_std)
        if len(self.prior_std) != 10:
            raise InvalidInputError(f"prior_std needs 10 values, got {len(self.prior_std)}")
        self._every = self.decimate or max(1, round(rate_hz / (2.0 * cutoff_hz)))
        gain, dgain = noise_gains(cutoff_hz, rate_hz)
        self._r_tau = self.sigma_tau ** 2 * gain
        self._var_ddq = self.sigma_dq ** 2 * dgain
        self._f: callable | None = None
        self.reset()

    def params(self) -> dict:
        return {"dynamics": self.dynamics, "sigma_tau": self.sigma_tau, "sigma_dq": self.sigma_dq,
                "cutoff_hz": self.cutoff_hz, "rate_hz": self.rate_hz,
                "decimate": self.decimate, "prior_std": list(self.prior_std)}

    def clone(self):
        return type(self)(**self.params())

    def reset(self) -> None:
        """Forget the payload: back to the prior (a new task, or a payload change)."""
        self.phi = np.zeros(10)
        self.P = np.diag(np.square(self.prior_std))
        self._lp = LowPass2(self.cutoff_hz, self.rate_hz, channels=21)
        self._prev_dq: np.ndarray | None = None
        self._count = 0
        self.updates = 0

    @property
    def n_bags(self) -> int:
        return 0

    def nbytes(self) -> int:
        return self.phi.nbytes + self.P.nbytes + 21 * 8 * 4

    def _dynamics(self):
        if self._f is None:
            self._f = load_dynamics(self.dynamics)
        return self._f

    # -- estimator seam ------------------------------------------------------------------
    def learn_one(self, x, flange=None, samples: Samples | None = None) -> None:
        """Filter the sample; every ``decimate``-th sample, one RLS update."""
        f = self._lp(np.asarray(x, dtype=float))
        q, dq, tau = f[:7], f[7:14], f[14:]
        prev, self._prev_dq = self._prev_dq, dq
        self._count += 1
        if prev is None or self._count % self._every:
            return
        ddq = (dq - prev) * self.rate_hz
        tau_robot, Y, M = self._dynamics()(q, dq, ddq)
        R = self._var_ddq * (M @ M.T)
        R[np.diag_indices(7)] += self._r_tau
        self.update(Y, tau - tau_robot, R)

    def update(self, Y: np.ndarray, r: np.ndarray, R: np.ndarray) -> None:
        """One RLS (Kalman) update with ``r = Y phi + e``, ``e ~ N(0, R)``."""
        PYt = self.P @ Y.T
        S = Y @ PYt + R
        K = np.linalg.solve(S, PYt.T).T
        self.phi = self.phi + K @ (r - Y @ self.phi)
        self.P = self.P - K @ S @ K.T
        self.P = 0.5 * (self.P + self.P.T)
        self.updates += 1

    def predict_one(self, x=None, flange=None, t: float = 0.0) -> PayloadEstimate:
        std = np.sqrt(np.maximum(np.diag(self.P), 0.0))
        return PayloadEstimate(t=t, phi=self.phi.copy(), std=std)

    def predict_many(self, X, F=None) -> np.ndarray:
        return np.tile(self.phi, (np.asarray(X).shape[0], 1))

    # -- persistence ---------------------------------------------------------------------
    def to_state(self) -> dict:
        lp = self._lp
        return {"params": self.params(), "phi": self.phi.tolist(), "P": self.P.tolist(),
                "count": self._count, "updates": self.updates,
                "prev_dq": None if self._prev_dq is None else self._prev_dq.tolist(),
                "filter": None if not lp._started else [lp._z1.tolist(), lp._z2.tolist()]}

    @classmethod
    def from_state(cls, state: dict):
        model = cls(**state["params"])
        model.phi = np.array(state["phi"], dtype=float).reshape(10)
        model.P = np.array(state["P"], dtype=float).reshape(10, 10)
        model._count = int(state["count"])
        model.updates = int(state["updates"])
        model._prev_dq = None if state["prev_dq"] is None else np.array(state["prev_dq"])
        if state["filter"] is not None:
            model._lp._z1, model._lp._z2 = (np.array(v) for v in state["filter"])
            model._lp._started = True
        return model


