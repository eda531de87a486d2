"""Measured joint signals on their way to the estimators (numpy only at import).

- :mod:`~iem.signals.gaps`: the one gap rule, what an irregular stream of time stamps means
  for every filter (:class:`GapRule`).
- :mod:`~iem.signals.blocks`: block points, the means of consecutive gap-free frames the
  estimators take (:class:`BlockFormer`, :class:`Blocks`).
- :mod:`~iem.signals.filters`: the causal low-pass and the state filter that gives ``ddq``
  (:class:`LowPass2`, :class:`StateFilter`).
- :mod:`~iem.signals.smoothing`: the causal smoothing of every model's output
  (:class:`ExponentialSmoother`).
- :mod:`~iem.signals.recording`: recorded joint states as arrays and their offline signal
  chain (:class:`Recording`, :func:`as_recording`, :func:`filtered`).
"""

from .blocks import BlockFormer, Blocks
from .filters import DEFAULT_CUTOFF_HZ, LowPass2, StateFilter
from .gaps import GapRule
from .recording import Recording, Signals, as_recording, filtered
from .smoothing import DEFAULT_TAU_S, ExponentialSmoother

__all__ = ["DEFAULT_CUTOFF_HZ", "DEFAULT_TAU_S", "BlockFormer", "Blocks",
           "ExponentialSmoother", "GapRule", "LowPass2", "Recording", "Signals",
           "StateFilter", "as_recording", "filtered"]
