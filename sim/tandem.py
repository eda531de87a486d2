"""The simulators in tandem: training samples for a whole payload family at one path point.

The paper runs simulators of the same robot alongside the real one, one per training payload,
so that at every new path point there is a labelled sample per payload. All of those
simulators share the arm's state, so their joint torques differ only by the payload term,
which is linear in the payload parameters::

    tau_k = RNEA(q, dq, ddq) + Y(q, dq, ddq) @ phi_k

One RNEA, one regressor and one matrix product give the samples of every payload at once.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from iem.errors import InvalidInputError

from .payload import Payload
from .robot import ArmModel


class TandemSimulators:
    """Noise-free simulators of the arm ``model`` (the default arm model's nominal arm by
    default), one per training payload.

    Args:
        payloads: the training payloads, or their ``(K, 10)`` phi in the paper's order.
        model: the Pinocchio model to use (a new nominal one by default; not shared, since a
            model owns its scratch data).
    """

    def __init__(self, payloads: Sequence[Payload] | np.ndarray,
                 model: ArmModel | None = None) -> None:
        if isinstance(payloads, np.ndarray):
            phi = np.array(payloads, dtype=float)
        else:
            phi = np.array([p.to_phi() for p in payloads], dtype=float)
        if phi.ndim != 2 or phi.shape[1] != 10 or phi.shape[0] == 0:
            raise InvalidInputError(
                f"payloads must give a (K, 10) phi with K >= 1, got {phi.shape}")
        phi.flags.writeable = False
        self.phi = phi
        self.model = ArmModel() if model is None else model

    def __len__(self) -> int:
        return self.phi.shape[0]

    def torques(self, q, dq, ddq) -> np.ndarray:
        """Joint torques of every training payload at one state, ``(K, 7)`` N·m."""
        tau0, regressor = self.model.rnea_and_regressor(q, dq, ddq)
        return tau0 + self.phi @ regressor.T

    def samples(self, q, dq, ddq) -> tuple[np.ndarray, np.ndarray]:
        """Inputs ``X = [q, dq, tau_k]`` ``(K, 21)`` and targets ``Y = phi_k`` ``(K, 10)``.

        ``Y`` is the family's read-only phi array itself (it never changes).
        """
        k = self.phi.shape[0]
        x = np.empty((k, 21))
        x[:, :7] = q
        x[:, 7:14] = dq
        x[:, 14:] = self.torques(q, dq, ddq)
        return x, self.phi

