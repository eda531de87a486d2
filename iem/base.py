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

Beyond that seam, :class:`Estimator` declares everything the online loop
(:class:`iem.online.OnlineIdentifier`), the plug-in service and the benchmarks call, and
:class:`BaseEstimator` gives each a default: an estimator subclasses it and overrides only
what it does differently (river's style), so a caller calls, never probes. An estimate's
``extra`` may carry ``"change": True`` (a payload change was detected at this sample) and
``"reset": True`` (earlier estimates are about another payload, or superseded: IEM+phys says
it of its estimates from its prior alone, already a mean, and of its first one with the
physics; the caller restarts any smoothing).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol, runtime_checkable

import numpy as np

from .types import PayloadEstimate

Samples = tuple[np.ndarray, np.ndarray] | Callable[[], tuple[np.ndarray, np.ndarray]]


def resolve(samples: Samples) -> tuple[np.ndarray, np.ndarray]:
    """The ``(X, Y)`` of a samples argument (calling it if it is lazy)."""
    return samples() if callable(samples) else samples


@runtime_checkable
class Estimator(Protocol):
    """What a caller may ask of an estimator (defaults: :class:`BaseEstimator`)."""

    name: str
    """The kind, a key of :data:`iem.model_kinds.MODELS`."""
    detects_changes: bool
    """Its estimates report payload changes (``extra["change"]``)."""
    tracks_payload: bool
    """It carries an estimate of the current payload from sample to sample (a posterior, a
    recursive fit): :meth:`resume` keeps it and :meth:`reset` forgets it. False: an estimate
    comes from what the model learnt and the sample alone."""
    background_learning: bool
    """It can train off the estimate path, in a worker thread (:meth:`set_background`)."""
    starts_from_payload: bool
    """It can start from a known payload (:meth:`start_from`: ``[estimate] initial_payload``,
    ``iem identify``'s file)."""
    rate_hz: float | None
    """The samples per second its signal filters were made for (IEM+phys's regression: the
    block points' rate); None: it has no filter and works at any rate. A service whose link
    gives another rate refuses the model."""
    trained_arm: dict | None
    """The arm it was trained for, as its model file records it (``{"crc32", "source"}``,
    :func:`iem.persistence.check_arm`); None: the nominal arm, or made in memory."""
    trained_family: str | None
    """The payload family its bags were trained on, as its model file records it; None: made
    in memory without one."""

    def learn_one(self, x: np.ndarray, flange: np.ndarray, samples: Samples) -> None: ...

    def predict_one(self, x: np.ndarray, flange: np.ndarray,
                    t: float = 0.0) -> PayloadEstimate: ...

    def predict_many(self, X: np.ndarray, F: np.ndarray) -> np.ndarray: ...

    def to_state(self) -> dict: ...

    def params(self) -> dict:
        """The hyper-parameters as given (``type(self)(**self.params())`` is a fresh clone);
        the factory specs among them (:data:`iem.factories.SPEC_KEYS`, at any depth) name
        what the model runs on, an arm by content."""

    @property
    def n_bags(self) -> int: ...

    def nbytes(self) -> int: ...

    def learn_predict_one(self, x: np.ndarray, flange: np.ndarray, samples: Samples,
                          t: float = 0.0) -> PayloadEstimate:
        """``learn_one`` then ``predict_one`` at the same point (the online loop's cycle;
        an estimator may share work between the two, the result is the same)."""

    def observe_one(self, x: np.ndarray, flange: np.ndarray) -> None:
        """Follow the current payload with one sample without training the model (the
        online loop's cycle when learning is off; IEM+phys updates its physics)."""

    def reset(self) -> None:
        """A new task, perhaps with another payload: forget the payload, never what was
        learnt."""

    def resume(self) -> None:
        """The signal stream restarted (a silence, a restart from a checkpoint, a new
        recording) with the payload unchanged: signal filters start again, what is known of
        the payload stays. The online loop calls it at the first sample of a stream and after
        every gap too long to bridge."""

    def gap(self, steps: int) -> None:
        """The next sample comes ``steps >= 2`` nominal cycles after the last one (``steps -
        1`` were lost): signal filters bridge them (:mod:`iem.signals.gaps`)."""

    def distrust(self) -> None:
        """A restart from a saved state: the payload it knew may have been swapped while
        nothing watched. Keep what it knew as a prior to be tested, and call its estimates
        ``unverified`` until live data have tested them."""

    def start_from(self, phi, std) -> None:
        """Start from the known payload ``phi`` with standard deviations ``std`` (10 values
        each), held as unverified until live data have tested it (where
        ``starts_from_payload``)."""

    def set_background(self, on: bool) -> None:
        """Train in a worker thread (True) or inline, reproducibly (False), from now on."""

    def go_live(self, on: bool = True, background: bool = True) -> None:
        """Set up for the link about to run: ``on``, a live link, where an estimate must
        never wait (training in the worker if ``background``, heavy work spread over
        samples, imports done now); off, a replay or a benchmark: everything inline and at
        once, reproducible to the bit. Calling it again with the same arguments changes
        nothing."""

    @property
    def busy(self) -> bool:
        """The last sample did heavy work: a caller with periodic work of its own may put it
        in the next sample instead."""

    @property
    def learning_cpu_s(self) -> float:
        """CPU time training took so far, s (a worker thread's, on a live link)."""

    def drain(self) -> None:
        """Wait until all submitted training has landed."""

    def stop(self) -> None:
        """Drain, then end any worker thread (a later learn starts one again)."""

    def close(self) -> None:
        """The task ended: finish what is being learnt (IEM: close the open bag)."""


class BaseEstimator:
    """The defaults of :class:`Estimator`'s capabilities, for an estimator to inherit: it
    detects no changes, tracks no payload between samples, cannot start from one, learns
    inline, works at any rate, and has nothing to set up, restart, bridge, drain, stop or
    close. A subclass implements the seam (``learn_one``, ``predict_one``, ``predict_many``,
    ``to_state``, ``params``, ``n_bags``, ``nbytes``)
    and overrides what it does beyond these defaults; :meth:`go_live`'s own set-up goes in
    the hook :meth:`_go_live`."""

    detects_changes = False
    tracks_payload = False
    background_learning = False
    starts_from_payload = False
    rate_hz: float | None = None
    trained_arm: dict | None = None
    trained_family: str | None = None

    def learn_predict_one(self, x, flange, samples: Samples, t: float = 0.0) -> PayloadEstimate:
        """:meth:`learn_one`, then :meth:`predict_one` at the same point."""
        self.learn_one(x, flange, samples)
        return self.predict_one(x, flange, t)

    def observe_one(self, x, flange) -> None:
        """Nothing: a model that follows the payload only by learning has, with learning
        off, nothing to follow (its estimates are predictions alone)."""

    def reset(self) -> None:
        """Nothing: no payload is held."""

    def resume(self) -> None:
        """Nothing: no signal filter to restart."""

    def gap(self, steps: int) -> None:
        """Nothing: no signal filter to bridge."""

    def distrust(self) -> None:
        """Nothing: no payload is carried from a saved state."""

    def start_from(self, phi, std) -> None:
        """Refused: no payload state to start from (``starts_from_payload`` is False)."""
        from .errors import InvalidInputError

        raise InvalidInputError(f"the {self.name} model cannot start from a known payload "
                                "(it keeps no payload state)")

    def set_background(self, on: bool) -> None:
        """Nothing: learning stays inline (``background_learning`` is False)."""

    def go_live(self, on: bool = True, background: bool = True) -> None:
        """:meth:`set_background` (``on and background``), then the model's own set-up
        (:meth:`_go_live`)."""
        self.set_background(on and background)
        self._go_live(on)

    def _go_live(self, on: bool) -> None:
        """The model's own set-up for a live link (``on``) or an offline run; none here."""

    @property
    def busy(self) -> bool:
        """Never: the heavy work is not spread over samples."""
        return False

    @property
    def learning_cpu_s(self) -> float:
        """0: no training is timed apart from the cycle."""
        return 0.0

    def drain(self) -> None:
        """Nothing pends."""

    def stop(self) -> None:
        """No worker to stop."""

    def close(self) -> None:
        """Nothing to finish."""
