"""What :func:`sim.identify.identify` returns: :class:`Identification`, the payload with its
covariance, and that covariance in the payload file's terms (mass, CoM, inertia about the
CoM) by first-order propagation."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from iem.types import PARAMS


@dataclass(frozen=True)
class Identification:
    """What :func:`~sim.identify.identify` found.

    Attributes:
        phi: the payload, paper order ``[m, mrx, mry, mrz, Ixx, Ixy, Ixz, Iyy, Iyz, Izz]``
            (kg, kg·m, kg·m², inertia about the flange origin), physically consistent.
        std: one standard deviation per parameter of ``phi``, same units.
        cov: the posterior covariance of ``phi`` (10x10; ``std`` is the root of its diagonal),
            e.g. to start an online estimator from this result as its prior.
        phi_unconstrained: the robust least-squares estimate before the consistency
            projection.
        prior_std: the prior's standard deviation per parameter (zero mean).
        determined_by: ``"data"`` or ``"prior"`` per parameter (see
            :data:`sim.identify.DATA_SHARE`).
        payload_std: std of the payload in the TOML's terms: ``mass`` (kg), ``com`` (m, 3),
            ``inertia`` (kg·m² about the CoM, 6), by first-order propagation from ``std``.
        report: figures of the run (samples, lag, path difference, residual RMS per joint
            before and after, noise inflation, outliers, min eigenvalue of the pseudo-inertia).
    """

    phi: np.ndarray
    std: np.ndarray
    cov: np.ndarray
    phi_unconstrained: np.ndarray
    prior_std: np.ndarray
    determined_by: tuple[str, ...]
    payload_std: dict
    report: dict = field(default_factory=dict, compare=False)

    def payload(self, name: str = "identified"):
        """The result as a :class:`sim.payload.Payload` (mass, CoM, inertia about the CoM)."""
        from sim.payload import Payload

        return Payload.from_phi(self.phi, name=name)

    def summary(self, name: str = "identified") -> dict:
        """The JSON summary: ``payload {mass, com, inertia}`` and ``std {mass, com,
        inertia}`` in the payload file's units, plus phi, its std and the report."""
        p = self.payload(name)
        return {
            "payload": {"name": p.name, "mass": p.mass, "com": list(p.com),
                        "inertia": list(p.inertia)},
            "std": {"mass": self.payload_std["mass"], "com": list(self.payload_std["com"]),
                    "inertia": list(self.payload_std["inertia"])},
            "units": {"mass": "kg", "com": "m, flange frame",
                      "inertia": "kg·m² about the CoM, [Ixx, Ixy, Ixz, Iyy, Iyz, Izz]"},
            "phi": dict(zip(PARAMS, self.phi.tolist(), strict=True)),
            "phi_std": dict(zip(PARAMS, self.std.tolist(), strict=True)),
            "determined_by": dict(zip(PARAMS, self.determined_by, strict=True)),
            "prior": {"mean": 0.0, "std": dict(zip(PARAMS, self.prior_std.tolist(),
                                                   strict=True))},
            "report": self.report,
        }


def _payload_terms(phi: np.ndarray) -> np.ndarray:
    """``[m, com (3), inertia about the CoM (6)]`` of ``phi``."""
    m = phi[0]
    c = phi[1:4] / m
    xx, xy, xz, yy, yz, zz = phi[4:]
    I_o = np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])
    I_c = I_o - m * (float(c @ c) * np.eye(3) - np.outer(c, c))
    return np.concatenate(([m], c, I_c[[0, 0, 0, 1, 1, 2], [0, 1, 2, 1, 2, 2]]))


def payload_std(phi: np.ndarray, cov: np.ndarray) -> dict:
    """First-order propagation of ``cov`` (phi) to mass, CoM and inertia about the CoM."""
    jac = np.empty((10, 10))
    for k in range(10):
        h = 1e-7 * max(1.0, abs(phi[k]))
        step = np.zeros(10)
        step[k] = h
        jac[:, k] = (_payload_terms(phi + step) - _payload_terms(phi - step)) / (2.0 * h)
    std = np.sqrt(np.maximum(np.diag(jac @ cov @ jac.T), 0.0))
    return {"mass": float(std[0]), "com": std[1:4].tolist(), "inertia": std[4:].tolist()}
