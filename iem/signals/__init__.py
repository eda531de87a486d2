"""Measured joint signals on their way to the estimators (numpy only at import).

- :mod:`~iem.signals.gaps`: the one gap rule, what an irregular stream of time stamps means
  for every filter (:class:`GapRule`).
- :mod:`~iem.signals.blocks`: block points, the means of consecutive gap-free frames the
  estimators take (:class:`BlockFormer`, :class:`Blocks`).
- :mod:`~iem.signals.filters`: the causal low-pass and the state filter that gives ``ddq``
  (:class:`LowPass2`, :class:`StateFilter`).
- :mod:`~iem.signals.smoothing`: the causal smoothing of every model's output
  (:class:`ExponentialSmoother`).
- :mod:`~iem.signals.recording`: recorded joint states as arrays (:class:`Recording`,
  :func:`as_recording`).
- :mod:`~iem.signals.rate`: the joint states' rate detected from time stamps, and the block
  size that keeps block points at about 100 a second (:func:`detect_rate`,
  :func:`block_frames_for`).
- :mod:`~iem.signals.offline`: the offline signal chain of ``iem calibrate`` and ``iem
  identify``, its gap rule included (:func:`prepare`, :class:`Signals`).
"""

from .blocks import BlockFormer, Blocks
from .filters import DEFAULT_CUTOFF_HZ, LowPass2, StateFilter
from .gaps import GapRule
from .offline import Signals, prepare
from .rate import block_frames_for, check_rate, detect_rate
from .recording import Recording, as_recording
from .smoothing import DEFAULT_TAU_S, ExponentialSmoother

__all__ = ["DEFAULT_CUTOFF_HZ", "DEFAULT_TAU_S", "BlockFormer", "Blocks",
           "ExponentialSmoother", "GapRule", "LowPass2", "Recording", "Signals",
           "StateFilter", "as_recording", "block_frames_for", "check_rate", "detect_rate",
           "prepare"]
