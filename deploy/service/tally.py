"""What one run of the service counted: one value, made afresh when the service activates,
that the status line and the summary read (:mod:`deploy.service.report`).

A run is an activation of the service (:meth:`deploy.service.loop.Service.activate` to
:meth:`~deploy.service.loop.Service.deactivate`): its points, silences and drops, the latencies
of its estimates, its CPU by thread and its wall time. What outlives a run is kept by the
parts that own it: the gate's decisions and writes (:class:`deploy.writeback.gate.SafetyGate`), the
link's frame counters, the model's bags, the checkpoints.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from iem.signals.blocks import BlockFormer

from .latency import LatencyWindow
from .pacing import LearningPace

__all__ = ["RunTally"]


@dataclass(eq=False)
class RunTally:
    """The counters of one run of the service (see the module docstring).

    Attributes:
        started: when the run started, ``time.monotonic()`` s.
        cycles: block points estimated.
        late: block points dropped unestimated, read too late to be worth it
            (:data:`deploy.service.loop.SKIP_LAG_S`).
        reader_skipped: block points the live reader dropped, its queue full.
        silences: controller silences begun.
        latencies: from a block's last frame's arrival to its estimate, s.
        ages: the age of a block's frames (their mean arrival) when its estimate is out, s.
        pace: whether the run keeps up with the controller, and the points it estimated
            without learning to stay current.
        step_cpu_s: CPU time of the estimator's steps, s (a part of the loop's).
        wall_s: the run's wall time, s (when it has ended).
        cpu_parts: CPU time by thread, s (when it has ended): the estimating loop's, the
            link reader's, the learning worker's and the checkpoints'.
        former: the reader's block former (when it has ended): the frames it bridged and
            those it did not use.
    """

    started: float
    cycles: int = 0
    late: int = 0
    reader_skipped: int = 0
    silences: int = 0
    latencies: LatencyWindow = field(default_factory=LatencyWindow)
    ages: LatencyWindow = field(default_factory=LatencyWindow)
    pace: LearningPace = field(default_factory=LearningPace)
    step_cpu_s: float = 0.0
    wall_s: float = 0.0
    cpu_parts: dict = field(default_factory=lambda: {
        "cycle": 0.0, "reader": 0.0, "learning": 0.0, "checkpoint": 0.0})
    former: BlockFormer | None = None

    @property
    def cpu_s(self) -> float:
        """The run's CPU time, all its threads, s."""
        return sum(self.cpu_parts.values())

    @property
    def skipped(self) -> int:
        """Block points dropped unestimated: too late, or the reader's queue full."""
        return self.late + self.reader_skipped

    @property
    def unlearnt(self) -> int:
        """Block points estimated without learning because the run was behind."""
        return self.pace.unlearnt
