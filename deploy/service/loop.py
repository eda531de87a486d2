"""The plug-in service: joint states in, identified payload out (``iem run``).

A pipeline of small parts, in one loop:

1. a reader (:mod:`deploy.service.reader`) forms the link's frames into block points, the means of
   ``[estimate] block_frames`` consecutive gap-free frames (100 points per second from a
   1 kHz controller), and hands them over once a block: in a thread of its own on a live
   link (reading never waits for estimating), in bulk for a replay;
2. the estimate step (:meth:`Service.step`, no thread of its own):
   :class:`iem.online.OnlineIdentifier` learns from the point (new bags are trained with the
   tandem simulators of the configured payload family) and estimates; the estimate is
   published where the link has a topic for it, and watched for a wrong arm model;
3. the load writer (:class:`deploy.writeback.writer.LoadWriter`): the smoothed estimate goes to the
   :class:`deploy.writeback.gate.SafetyGate` (with the raw estimate, for its uncertainty, the
   point's pose, for the torque a write would correct, and the link's wire range check,
   :func:`deploy.service.capabilities.wire_check_for`), a load it lets through to the link's
   ``send`` (libfranka ``setLoad`` semantics), acknowledgements and the controller's reports of the
   load in force back to the gate; the gate's verdict goes out once a second on a link with a status
   topic (ROS 2 ``/diagnostics``);
4. the checkpointer (:class:`deploy.service.checkpointer.Checkpointer`): the model saved every
   ``checkpoint_period_s`` (a copy, written in a background thread) and at exit, atomically:
   a failed save leaves the last good file.

Its lifecycle, as ros2_control's hardware interfaces have it (each state says what is open):

- ``unconfigured``: nothing open;
- :meth:`Service.configure` -> ``inactive``: the CPU wake-up latency held (if configured),
  the model loaded (or trained if there is none and ``train_if_missing``; temporary files of
  an interrupted save removed first), its learning worker live, the link open, the gate
  built; nothing read yet;
- :meth:`Service.activate` -> ``active``: the reader reads, the checkpointer is due, systemd
  is told READY; a fresh :class:`deploy.service.tally.RunTally` counts the run;
  :meth:`Service.run` activates, loops until stopped and deactivates;
- :meth:`Service.deactivate` -> ``inactive``: the reader stopped, the run's wall and CPU
  time taken, systemd told STOPPING;
- :meth:`Service.shutdown` -> ``finalized``: the last checkpoint saved, the learning worker
  stopped, the link closed, the latency limit released.

A silent controller stops the writes until it returns. A link failure ends the run with the
error (exit status 2: under systemd, the unit restarts it; configuration errors exit 78 and
are not restarted, see :mod:`deploy.cli`). Every failure is kept in order
(:class:`deploy.service.failures.Failures`): the first is what the run ends with, and what fails
after it (a vanished controller's link then fails to close) follows it, never replaces it.
``Service.stop()`` (SIGTERM, SIGINT) ends the loop after the current block.

The gate decides on one clock for the whole run, whatever the link and whatever happens
(points and silences alike): this PC's monotonic clock on a live link, the controller's own
time stamps for a replay (``gate_clock``).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from deploy.config import CellConfig, ConfigError
from deploy.model.setup import block_frames_of, checked_model, link_rate
from deploy.writeback.gate import SafetyGate
from deploy.writeback.writer import LoadWriter
from firmware_bridge.links import DiagnosticsSink, EstimatePublisher, link_kind
from iem.online import OnlineIdentifier
from iem.signals.blocks import BlockFormer
from iem.signals.filters import StateFilter, usable_cutoff
from iem.signals.smoothing import ExponentialSmoother

from .arm_watch import ArmWatch
from .capabilities import check_sink, wire_check_for
from .checkpointer import Checkpointer
from .failures import Failures
from .report import log_rate, status_text, summary_of
from .sdnotify import Notifier
from .status import StatusLine
from .tally import RunTally

log = logging.getLogger("iem.service")

DIAGNOSTICS_PERIOD_S = 1.0
"""The gate's verdict goes out on a link with a status topic (ROS 2 ``/diagnostics``) once
a second, as ROS diagnostics are."""
SKIP_LAG_S = 2.0
"""A block point older than this when read is dropped (counted in ``skipped``): even
estimating without learning has fallen hopelessly behind."""

UNCONFIGURED, INACTIVE, ACTIVE, FINALIZED = "unconfigured", "inactive", "active", "finalized"
"""The service's lifecycle states (see the module docstring)."""


@dataclass
class CycleRecord:
    """What the service made of one block point (given to ``on_cycle`` observers):
    ``state`` the point (means of its frames), ``latency_s`` the time from its last frame's
    arrival to its estimate, ``age_s`` the age of its frames' mean arrival then (NaN for a
    replay: no arrival times)."""

    state: object
    raw: object
    smoothed: np.ndarray
    latency_s: float
    age_s: float = math.nan


class Service:
    """The running plug-in (see the module docstring for its parts).

    Args:
        config: the cell configuration.
        link: an open link (a joint-state source and, unless replaying, a payload sink);
            None: open the configured one.
        model: the estimator to use; None: :func:`load_or_train_model`.
        notifier: systemd notifications (default: from the environment).
        status: the live status line (default: per ``[log] status_line``).
        write: send loads the gate lets through (False: decide only, as for replay).
        gate_clock: ``"monotonic"``: the gate's times are this PC's monotonic clock;
            ``"controller"``: the joint states' own time stamps (a replay as fast as
            possible then decides as the cell did at recorded pace).
        threaded_reader: read the link in a thread of its own (:class:`deploy.service.reader.
            LinkReader`), so reading never waits for estimating; else in bulk in the loop's
            thread (:class:`deploy.service.reader.BatchReader`). None: threaded for a live link
            (``gate_clock`` monotonic), not for a replay, which must lose nothing and run as
            fast as the estimator goes.
        rate_hz: joint states a second the link delivers; None: the configured link's, its
            kind's or wire profile's (:func:`deploy.model.setup.link_rate`); a replay gives
            its recording's.
    """

    def __init__(self, config: CellConfig, link=None, model=None,
                 notifier: Notifier | None = None, status: StatusLine | None = None,
                 write: bool = True, gate_clock: str = "monotonic",
                 threaded_reader: bool | None = None, rate_hz: float | None = None) -> None:
        if gate_clock not in ("monotonic", "controller"):
            raise ValueError(f"gate_clock {gate_clock!r}; valid are 'monotonic', 'controller'")
        self.gate_clock = gate_clock
        self.threaded_reader = (gate_clock == "monotonic" if threaded_reader is None
                                else bool(threaded_reader))
        self.config = config
        self.link = link
        self._rate_hz = rate_hz
        self.model = model
        self.notifier = Notifier() if notifier is None else notifier
        self.status = status if status is not None else StatusLine.from_config(config.log)
        self.write = write
        self.gate: SafetyGate | None = None
        """The safety gate, built complete by :meth:`open` (the link's wire check, the arm's
        regressor)."""
        self._diagnostics = None  # the link's status topic, if it has one (set by run)
        self._next_diagnostics = 0.0
        self.arm_watch = ArmWatch()
        """Says once when the mass stays clearly below zero (a wrong arm model)."""
        self.checkpointer = Checkpointer(config.model.path, config.model.checkpoint_period_s,
                                         saves=not link_kind(config.link.kind).recorded)
        self.writer: LoadWriter | None = None
        self._publish = None  # the link's publish_estimate, if it has one (set by run)
        self.on_cycle: list[Callable[[CycleRecord], None]] = []
        self._stop = threading.Event()
        self.tally: RunTally | None = None
        """What the current or last run counted (None before the first run)."""
        self.silent = False
        """The controller is silent: the writes are stopped until it is back."""
        self.failures = Failures()
        """Every failure of this service, the first first."""
        self.lifecycle = UNCONFIGURED
        """Where it is in its lifecycle (see the module docstring)."""
        self.cpu_latency = None
        """The held CPU wake-up latency limit (``[host] cpu_dma_latency_us``), or None."""
        self.reader = None
        """The active run's reader (:mod:`deploy.service.reader`); None while inactive."""
        self._model_checked = False  # configure got the model: shutdown saves it
        self._cpu0 = (0.0, 0.0, 0.0)  # the loop's, learning's and checkpoints' CPU at start

    @property
    def checkpoints(self) -> int:
        """Saves of the model so far."""
        return self.checkpointer.count

    # -- the lifecycle ---------------------------------------------------------------------
    def configure(self) -> Service:
        """Unconfigured -> inactive: hold the CPU latency limit, load the model, open the
        link, build the gate (see the module docstring). A failure is recorded and raised;
        :meth:`shutdown` closes what was opened."""
        self._expect(UNCONFIGURED, "configure")
        try:
            self._configure()
        except BaseException as exc:
            self.failures.add("configuring", exc)
            raise
        self.lifecycle = INACTIVE
        return self

    open = configure
    """The same as :meth:`configure`."""

    def _configure(self) -> None:
        from deploy.model.training import tandem_for
        from sim.robot import ArmModel

        from .host import hold_cpu_latency

        if self.cpu_latency is None:  # first: a host that refuses it fails before training
            self.cpu_latency = hold_cpu_latency(self.config.host.cpu_dma_latency_us)
            if self.cpu_latency is not None:
                log.info("holding a CPU wake-up latency limit of %d µs on %s (in force: %d "
                         "µs)", self.cpu_latency.latency_us, self.cpu_latency.device,
                         self.cpu_latency.effective_us, extra={"event": "cpu_latency"})
        self.model, arm = checked_model(self.config, self.model)
        self._model_checked = True
        # a live link: learning and heavy work never hold up estimating; a replay: inline
        # and at once, reproducible
        self.model.go_live(self.threaded_reader,
                           background=self.config.estimate.background_learning)
        if self.link is None:
            from firmware_bridge.errors import LogFileError
            from firmware_bridge.links import open_link

            lc = self.config.link
            try:
                self.link = open_link(lc.kind, lc.channel, profile=lc.profile,
                                      silence_timeout=lc.silence_timeout_s,
                                      **self.config.link_options())  # [ros2] for kind ros2
            except LogFileError as exc:  # a recording cell.toml names: a restart cannot fix
                raise ConfigError(f"{self.config.source}: [link] channel = {lc.channel!r}: "
                                  f"{exc}") from exc
        self.rate_hz = self._rate_hz or link_rate(self.config)
        self.block_frames = block_frames_of(self.config, self.rate_hz)
        self.point_rate_hz = self.rate_hz / self.block_frames
        log_rate(self)
        self.kinematics = ArmModel(arm=arm, description=self.config.arm.description())
        self._zeros = np.zeros(7)
        self.tandem = tandem_for(self.config.model.family, arm)
        self.online = self.identifier(self.model)
        # out_of_wire_range before send (a CAN kind's link must declare its profile); the
        # torque bound of a write along the recent motion
        self.gate = SafetyGate(self.config.gate,
                               wire_check_for(self.link, self.config.link.kind), self._regressor)

    def identifier(self, model) -> OnlineIdentifier:
        """The online loop this service runs ``model`` in (its filters, smoothing and block
        former, as configured; after :meth:`open`)."""
        est = self.config.estimate
        return OnlineIdentifier(
            model, self.kinematics.flange_position, self.tandem.samples, learn=est.learn,
            state_filter=StateFilter(usable_cutoff(est.filter_cutoff_hz, self.point_rate_hz),
                                     self.point_rate_hz),
            smoother=ExponentialSmoother(tau_s=est.smoothing_tau_s,
                                         dt=1.0 / self.point_rate_hz),
            former=self._former())

    def _regressor(self, q, dq):
        """The payload regressor at a pose of the recent motion (``ddq = 0``): the gate's
        bound of the joint-torque error a load leaves."""
        return self.kinematics.payload_regressor(q, dq, self._zeros)

    def _former(self) -> BlockFormer:
        return BlockFormer(self.block_frames, self.rate_hz)

    def stop(self) -> None:
        """Ask the loop to end after the current block (safe from a signal handler)."""
        self._stop.set()

    @property
    def stopping(self) -> bool:
        return self._stop.is_set()

    def activate(self) -> None:
        """Inactive -> active: a fresh tally, the load writer on the link, the reader
        reading, the checkpointer due, systemd told READY."""
        from .reader import BatchReader, LinkReader

        self._expect(INACTIVE, "activate")
        model = self.model
        # the link as it is now; a kind that writes loads needs a PayloadSink (refused else)
        write = self.write and link_kind(self.config.link.kind).sink
        check_sink(self.link, write)
        self.writer = LoadWriter(self.gate, self.link, write)
        self._publish = (self.link.publish_estimate if isinstance(self.link, EstimatePublisher)
                         else None)  # a link with topics
        self._diagnostics = self.link if isinstance(self.link, DiagnosticsSink) else None
        self._next_diagnostics = 0.0
        self.online.learn = self.config.estimate.learn  # a run starts current
        self.tally = RunTally(started=time.monotonic())
        self._cpu0 = (time.thread_time(), model.learning_cpu_s, self.checkpointer.cpu_s)
        self.checkpointer.start(self.tally.started)
        self.reader = (LinkReader if self.threaded_reader else BatchReader)(
            self.link, self.config.link.silence_timeout_s, self._former()).start()
        self.lifecycle = ACTIVE
        self.notifier.ready(f"identifying the payload; {model.n_bags} bags")
        log.info("running: link %s, model %s (%d bags), writes %s, %g block points per s",
                 getattr(self.link, "name", self.link), model.name, model.n_bags,
                 "on" if self.writer.sink is not None else "off", self.point_rate_hz,
                 extra={"event": "started"})

    def deactivate(self) -> None:
        """Active -> inactive: the reader stopped, the run's wall and CPU time taken, the
        status line cleared, systemd told STOPPING. A failure is recorded; it is raised
        only if it is the service's first."""
        self._expect(ACTIVE, "deactivate")
        self.failures.run_all(self._deactivate_steps())

    def _deactivate_steps(self) -> list:
        self.lifecycle = INACTIVE
        return [("stopping the reader", self._account),
                ("clearing the status line", self.status.clear),
                ("telling systemd", self.notifier.stopping)]

    def shutdown(self) -> None:
        """Any state -> finalized: deactivated if active, then the final checkpoint
        (synchronous: the learning worker's pending work lands first), the CPU latency
        limit released, the worker stopped, the link closed. Each step runs even if one
        before it failed; a failure is recorded, and raised only if it is the service's
        first (after a failed run, the run's failure is the one on its way)."""
        if self.lifecycle == FINALIZED:
            return
        steps = []
        if self.lifecycle == ACTIVE:
            steps += self._deactivate_steps()
        if self._model_checked:  # what it learnt, and a model trained at start
            steps.append(("saving the model", self.checkpoint))
        # the loop is over: a failing worker or link must not keep cores polling
        steps.append(("releasing the CPU latency limit", self._release_cpu_latency))
        if self.model is not None:
            steps.append(("stopping the learning worker", self.model.stop))
        if self.link is not None:
            steps.append(("closing the link", self.link.close))
        steps.append(("closing the systemd notification socket", self.notifier.close))
        self.lifecycle = FINALIZED
        self.failures.run_all(steps)

    close = shutdown
    """The same as :meth:`shutdown`."""

    def _expect(self, state: str, action: str) -> None:
        if self.lifecycle != state:
            raise RuntimeError(f"the service cannot {action} while {self.lifecycle}; it must be "
                               f"{state}")

    def _release_cpu_latency(self) -> None:
        if self.cpu_latency is not None:
            self.cpu_latency.close()
            self.cpu_latency = None

    # -- the loop --------------------------------------------------------------------------
    def run(self, duration: float | None = None,
            until: Callable[[], bool] | None = None) -> dict:
        """Run until stopped, ``duration`` s passed, ``until()`` is true or a replay ends:
        configured first if it is not, activated, deactivated at the end (see the module
        docstring). A failure is recorded and raised; one while deactivating after it
        follows it. Returns the run's summary."""
        if self.lifecycle == UNCONFIGURED:
            self.configure()
        self.activate()
        try:
            self._loop(duration, until)
        except BaseException as exc:
            self.failures.add("running", exc)
            raise
        finally:
            self.deactivate()
        return self.summary()

    def _loop(self, duration: float | None, until: Callable[[], bool] | None) -> None:
        reader, started = self.reader, self.tally.started
        timeout = self.config.link.silence_timeout_s
        watchdog = self.notifier.watchdog_period()
        next_watchdog = started
        while not self._stop.is_set():
            now = time.monotonic()
            if (duration is not None and now - started >= duration) or (
                    until is not None and until()):
                break
            if watchdog is not None and now >= next_watchdog:
                self.notifier.watchdog()
                next_watchdog = now + watchdog
            item = reader.get(timeout + 0.5)
            if item is None or item.kind == "silent":
                self._silent_item(item)
                continue
            if item.kind == "end":
                break
            if item.kind == "error":
                raise item.value
            out = self.step(item)
            if out is not None:
                self._after_step(out, started)

    def _gate_time(self, controller_t: float) -> float:
        """The run's one clock for the gate: the controller's time ``controller_t`` (s) of a
        point or a silence, or this PC's monotonic clock now (``gate_clock``)."""
        return controller_t if self.gate_clock == "controller" else time.monotonic()

    def _silent_item(self, item) -> None:
        """Nothing read (None) or a controller silence: the writes stop; the gate decides
        (and counts) on no write, at the silence's time on the run's clock."""
        if item is None:
            return
        self._controller_silent(item.value)
        t = self._gate_time(item.t)
        if math.isfinite(t):  # (the controller's clock before its first frame: no time yet)
            self.gate.step(t)  # a silence: no estimate, the hold counted

    def _after_step(self, out: CycleRecord, started: float) -> None:
        """The load writer, the checkpointer and the status line after one estimate."""
        now = time.monotonic()
        self.writer.step(self._gate_time(out.state.t), out.smoothed, out.raw, out.state,
                         self.model.busy)
        self.checkpointer.tick(now, self.model)
        if self._diagnostics is not None and now >= self._next_diagnostics:
            self._next_diagnostics = now + DIAGNOSTICS_PERIOD_S
            self._diagnostics.publish_diagnostics(self.gate.verdict())
        if self.status.due(now):
            self.status.show(status_text(self, now - started, out))

    def _account(self) -> None:
        """The run's wall time and CPU by thread; the reader stopped."""
        tally, reader = self.tally, self.reader
        cpu0, learn0, save0 = self._cpu0
        tally.wall_s = time.monotonic() - tally.started
        cycle_cpu = time.thread_time() - cpu0
        reader.stop()
        tally.reader_skipped = reader.skipped
        tally.cpu_parts = {"cycle": cycle_cpu,
                           "reader": reader.cpu_s if self.threaded_reader else 0.0,
                           "learning": self.model.learning_cpu_s - learn0,
                           "checkpoint": self.checkpointer.cpu_s - save0}
        tally.former = reader.former
        self.reader = None

    def step(self, item) -> CycleRecord | None:
        """One block point through the estimator (no thread of its own): pace against the
        controller on a live link, learn and estimate, publish, record the latency, watch
        the arm model, tell the observers. None: the point was dropped (hopelessly late)."""
        state, tally = item.value, self.tally
        if self.silent:
            self._controller_back()
        arrived = item.frame_time  # the block's last frame's arrival (epoch s)
        # a block a silence closed is as old as the silence: that is no lag of the service
        max_lag = (self.config.estimate.max_lag_s
                   if self.gate_clock == "monotonic" and not item.flushed else 0.0)
        if max_lag:
            lag = time.time() - arrived if arrived > 0 else 0.0
            if lag > SKIP_LAG_S:
                tally.late += 1  # hopelessly behind: drop the point
                return None
            self._pace(lag, max_lag)
        cpu0 = time.thread_time()
        raw, smoothed = self.online.step_block(state)
        tally.step_cpu_s += time.thread_time() - cpu0
        if self._publish is not None:  # the ros2 link: the estimate on its topics, at its
            self._publish(raw, smoothed)  # own rate
        done = time.time()
        latency = done - arrived if arrived > 0 else math.nan
        age = (done - 0.5 * (arrived + item.first_time) if arrived > 0 and item.first_time > 0
               else math.nan)
        tally.latencies.add(latency)
        tally.ages.add(age)
        tally.cycles += 1
        self.arm_watch.observe(state.t, smoothed, raw)
        record = CycleRecord(state, raw, smoothed, latency, age)
        for observer in self.on_cycle:
            observer(record)
        return record

    def checkpoint(self) -> None:
        """Save the model now (atomic), waiting for a background save first."""
        self.checkpointer.save_now(self.model)

    # -- events ----------------------------------------------------------------------------
    def _controller_silent(self, why: str) -> None:
        if not self.silent:
            self.silent = True
            self.tally.silences += 1
            self.gate.controller_silent(True)
            log.warning("controller silent: writes stopped (%s)", why,
                        extra={"event": "controller_silent"})
            self.notifier.status("controller silent: writes stopped")
        self.status.show("controller silent: writes stopped", force=True)

    def _pace(self, lag: float, max_lag: float) -> None:
        """Learn or not, as the service keeps up with the controller (:class:`deploy.service.pacing.
        LearningPace`)."""
        pace = self.tally.pace
        if pace.observe(lag, max_lag):
            self.online.learn = self.config.estimate.learn and not pace.behind

    def _controller_back(self) -> None:
        self.silent = False
        self.gate.controller_silent(False)
        self.online.resume()  # the signal was interrupted; the payload estimate stays
        log.info("controller back: writes resume", extra={"event": "controller_back"})
        self.notifier.status("identifying the payload")

    # -- reporting -----------------------------------------------------------------------
    def summary(self) -> dict:
        """What the last run did (:func:`deploy.service.report.summary_of`)."""
        return summary_of(self)

