"""LS: classical recursive least squares on the payload regressor (the physics anchor).

What a robotics engineer would pick instead of learning: with the robot's own model, the
torque the payload adds is linear in its parameters, ``tau - tau_robot(q, dq, ddq) =
Y(q, dq, ddq) phi``. Recursive least squares (in Kalman form, 7 equations per update):

    S = Y P Y^T + R,  K = P Y^T S^-1,  phi <- phi + K (r - Y phi),  P <- P - K S K^T

The equations ``(Y, r, R)`` come from :class:`iem.physics.regression.PayloadRegression`: ``q``,
``dq`` and ``tau`` through the same causal 2nd-order Butterworth low-pass (default 20 Hz), ``ddq``
the backward difference of the filtered ``dq``, and ``R`` the filtered torque noise plus the
errors-in-variables term of the ``ddq`` noise (``M(q) diag(sigma_ddq²) M(q)^T``), so the
reported uncertainty ``std = sqrt(diag(P))`` stays honest. The filtered torque noise is
correlated over about ``rate / (2 cutoff)`` samples, so the filter updates only every
``decimate`` samples (default: that correlation length). The prior is zero with a standard
deviation sized to the Panda's rated payload (3 kg, CoM within 0.1 m, inertia within
0.01 kg·m²): the classical method knows the robot's rating, not the payload family.

The robot model is given by the caller, named, not passed (see :mod:`iem.physics.regression`), and
imported only when the model first learns.
"""

from __future__ import annotations

import numpy as np

from ..base import BaseEstimator, Samples
from ..errors import InvalidInputError
from ..physics.posterior import DEFAULT_PRIOR_STD
from ..physics.regression import PayloadRegression, required_dynamics
from ..sensor import DEFAULT_SENSOR
from ..types import DEFAULT_BLOCK_FRAMES, NOMINAL_POINT_RATE_HZ, PayloadEstimate

__all__ = ["RecursiveLeastSquares"]


class RecursiveLeastSquares(BaseEstimator):
    """Recursive least squares on the payload regressor.

    Args:
        dynamics: the robot model (required): ``"module:function[@ARG]"`` of its factory
            (see :mod:`iem.physics.regression`), stored in the model file.
        sigma_tau: torque noise of one measured frame, N·m.
        cutoff_hz: low-pass cut-off for q, dq and tau, Hz.
        rate_hz: sample rate, Hz (the block points', :mod:`iem.signals.blocks`: 100 Hz).
        decimate: update every this many samples (0: the noise correlation length).
        prior_std: prior standard deviation per parameter (10 values).
        point_frames: frames averaged into each sample (a block point's; 1: samples are
            frames): a sample's noise is a frame's over its square root.
    """

    name = "LS"
    tracks_payload = True
    """The estimate and its covariance carry from sample to sample."""

    def __init__(self, dynamics: str | None = None,
                 sigma_tau: float = DEFAULT_SENSOR.sigma_tau,
                 sigma_dq: float = DEFAULT_SENSOR.sigma_dq, cutoff_hz: float = 20.0,
                 rate_hz: float = NOMINAL_POINT_RATE_HZ,
                 decimate: int = 0, prior_std=DEFAULT_PRIOR_STD,
                 point_frames: int = DEFAULT_BLOCK_FRAMES) -> None:
        self.dynamics = required_dynamics(dynamics, "RecursiveLeastSquares (LS)")
        self.sigma_tau = float(sigma_tau)
        self.sigma_dq = float(sigma_dq)
        self.cutoff_hz = float(cutoff_hz)
        self.rate_hz = float(rate_hz)
        self.decimate = int(decimate)
        self.point_frames = int(point_frames)
        self.prior_std = tuple(float(v) for v in prior_std)
        if len(self.prior_std) != 10:
            raise InvalidInputError(f"prior_std needs 10 values, got {len(self.prior_std)}")
        every = self.decimate or max(1, round(rate_hz / (2.0 * cutoff_hz)))
        root = np.sqrt(self.point_frames)  # a block point's mean: 1/n of the noise variance
        self._regression = PayloadRegression(dynamics, self.sigma_tau / root,
                                             self.sigma_dq / root, self.cutoff_hz,
                                             self.rate_hz, every=every)
        self.reset()

    def params(self) -> dict:
        return {"dynamics": self.dynamics, "sigma_tau": self.sigma_tau, "sigma_dq": self.sigma_dq,
                "cutoff_hz": self.cutoff_hz, "rate_hz": self.rate_hz,
                "decimate": self.decimate, "prior_std": list(self.prior_std),
                "point_frames": self.point_frames}

    def clone(self):
        return type(self)(**self.params())

    def reset(self) -> None:
        """Forget the payload: back to the prior (a new task, or a payload change)."""
        self.phi = np.zeros(10)
        self.P = np.diag(np.square(self.prior_std))
        self._regression.reset()
        self.updates = 0
        self._steps = 1

    def resume(self) -> None:
        """The signal stream restarted, the payload did not: the filter starts again, the
        estimate and its covariance stay."""
        self._regression.reset()

    def gap(self, steps: int) -> None:
        """The next sample comes ``steps`` nominal cycles after the last (see
        :mod:`iem.signals.gaps`): the filter bridges the lost ones."""
        self._steps = int(steps)

    @property
    def n_bags(self) -> int:
        return 0

    def nbytes(self) -> int:
        return self.phi.nbytes + self.P.nbytes + 21 * 8 * 4

    # -- estimator seam ------------------------------------------------------------------
    def learn_one(self, x, flange=None, samples: Samples | None = None) -> None:
        """Filter the sample; every ``decimate``-th sample, one RLS update."""
        equation = self._regression(x, steps=self._steps)
        self._steps = 1
        if equation is not None:
            self.update(*equation)

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
        # least squares knows its spread, but neither tests its data nor knows a training set
        return PayloadEstimate(t=t, phi=self.phi.copy(), std=std, nis=None, ood=None,
                               determined=None)

    def predict_many(self, X, F=None) -> np.ndarray:
        return np.tile(self.phi, (np.asarray(X).shape[0], 1))

    # -- persistence ---------------------------------------------------------------------
    def to_state(self) -> dict:
        return {"params": self.params(), "phi": self.phi.tolist(), "P": self.P.tolist(),
                "updates": self.updates, **self._regression.to_state()}

    @classmethod
    def from_state(cls, state: dict):
        model = cls(**state["params"])
        model.phi = np.array(state["phi"], dtype=float).reshape(10)
        model.P = np.array(state["P"], dtype=float).reshape(10, 10)
        model.updates = int(state["updates"])
        model._regression.set_state(state)
        return model


