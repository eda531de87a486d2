"""The seam every estimator implements (river's style: ``learn_one`` / ``predict_one``).

An estimator sees one controller cycle at a time:

- ``x``: the measured input ``[q, dq, tau]`` (21 values: rad, rad/s, N·m);
- ``flange``: the flange position of the measured ``q`` (3 values, m), for the bag router;
- ``samples``: the tandem simulators' training samples at this point, ``(X (K, 21),
  Y (K, 10))``, or a zero-argument callable that returns them (computed only if the
  estimator needs them: most points never do).

``learn_one`` updates the model with the point; ``predict_one`` returns a
:class:`iem.types.PayloadEstimate` and never changes the model. ``predict_many`` is the
vectorised form of ``predict_one``. ``to_state``/``from_state`` give a plain-data snapshot
for :mod:`iem.persistence`. ``n_bags`` and ``nbytes`` let the checks bound the memory.

Optional: ``observe_one(x, flange)`` updates what an estimator tracks about the current
payload without training its model (IEM+phys's physics; :class:`iem.online.OnlineIdentifier`
calls it instead of ``learn_one`` when learning is off), ``reset()`` forgets the payload
(a new task), never what was learnt, and ``resume()`` says the signal stream restarted (a
silence, a restart from a checkpoint, a new recording) with the payload unchanged: signal
filters start again, what is known of the payload stays (:class:`iem.online.OnlineIdentifier`
calls it at the first sample of a stream and after every long gap), and ``gap(k)`` says that
the next sample comes ``k >= 2`` nominal cycles after the last one (``k - 1`` were lost; the
signal filters bridge them: :mod:`iem.gaps`). An estimate's ``extra`` may
carry ``"change": True`` (a payload change was detected at this sample) and ``"reset": True``
(earlier estimates are about another payload, or superseded: IEM+phys says it of its
estimates from its prior alone, already a mean, and of its first one with the physics; the
caller restarts any smoothing).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Protocol, runtime_checkable

import numpy as np

from .types import PayloadEstimate

Samples = tuple[np.ndarray, np.ndarray] | Callable[[], tuple[np.ndarray, np.ndarray]]


def resolve(samples: Samples) -> tuple[np.ndarray, np.ndarray]:
    """The ``(X, Y)`` of a samples argument (calling it if it is lazy)."""
    return samples() if callable(samples) else samples


def load_factory(spec: str, what: str):
    """Resolve ``"module:function"`` and call the factory: ``function()``; or
    ``"module:function@ARG"``: ``function(ARG)`` (e.g. an arm file's path). ``what`` names
    the setting in the error."""
    from .errors import InvalidInputError

    target, at, arg = spec.partition("@")
    try:
        module, _, attr = target.partition(":")
        factory = getattr(importlib.import_module(module), attr)
    except (ImportError, AttributeError, ValueError) as exc:
        raise InvalidInputError(f"{what} {spec!r} is not 'module:function[@ARG]' naming a "
                                f"factory: {exc}") from exc
    return factory(arg) if at else factory()


@runtime_checkable
class Estimator(Protocol):
    name: str

    def learn_one(self, x: np.ndarray, flange: np.ndarray, samples: Samples) -> None: ...

    def predict_one(self, x: np.ndarray, flange: np.ndarray,
                    t: float = 0.0) -> PayloadEstimate: ...

    def predict_many(self, X: np.ndarray, F: np.ndarray) -> np.ndarray: ...

    def to_state(self) -> dict: ...

    @property
    def n_bags(self) -> int: ...

    def nbytes(self) -> int: ...
