"""The plug-in service: joint states in, identified payload out (``iem run``).

A pipeline of small parts, in one loop:

1. a reader (:mod:`deploy.reader`) forms the link's frames into block points, the means of
   ``[estimate] block_frames`` consecutive gap-free frames (100 points per second from a
   1 kHz controller), and hands them over once a block: in a thread of its own on a live
   link (reading never waits for estimating), in bulk for a replay;
2. the estimate step (:meth:`Service.step`, no thread of its own):
   :class:`iem.online.OnlineIdentifier` learns from the point (new bags are trained with the
   tandem simulators of the configured payload family) and estimates; the estimate is
   published where the link has a topic for it, and watched for a wrong arm model;
3. the load writer (:class:`deploy.load_writer.LoadWriter`): the smoothed estimate goes to
   the :class:`deploy.gate.SafetyGate` (with the raw estimate, for its uncertainty, and the
   link's wire range check, :func:`wire_check_of`), a load it lets through to the link's
   ``send`` (libfranka ``setLoad`` semantics), acknowledgements back to the gate;
4. the checkpointer (:class:`deploy.checkpointer.Checkpointer`): the model saved every
   ``checkpoint_period_s`` (a copy, written in a background thread) and at exit, atomically:
   a failed save leaves the last good file.

Around the loop: temporary files of an interrupted save are removed at start
(:func:`iem.persistence.remove_stale_temporaries`); the model is loaded (or trained if there
is none and ``train_if_missing``); a silent controller stops the writes until it returns;
link failures end the run with the error (exit status 2: under systemd, the unit restarts
it; configuration errors exit 78 and are not restarted, see :mod:`deploy.cli`).
``Service.stop()`` (SIGTERM, SIGINT) ends the loop after the current block.
"""

from __future__ import annotations

import functools
import logging
import math
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path as FsPath

import numpy as np

from iem.blocks import BlockFormer
from iem.filters import StateFilter
from iem.online import OnlineIdentifier
from iem.persistence import load_model, remove_stale_temporaries, save_model
from iem.smoothing import ExponentialSmoother

from .arm_watch import ArmWatch
from .checkpointer import Checkpointer
from .config import CellConfig
from .gate import SafetyGate
from .latency import LatencyWindow
from .load_writer import LoadWriter
from .sdnotify import Notifier
from .status import StatusLine

log = logging.getLogger("iem.service")

SKIP_LAG_S = 2.0
"""A block point older than this when read is dropped (counted in ``skipped``): even
estimating without learning has fallen hopelessly behind."""


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


def link_rate(config: CellConfig) -> float:
    """Joint states per second the configured link delivers, as its kind and wire profile say
    (:func:`firmware_bridge.links.rate_hz`)."""
    from firmware_bridge.links import rate_hz

    return rate_hz(config.link.kind, config.link.profile)


def point_rate(config: CellConfig) -> float:
    """Block points per second the estimator works at: the link's rate over ``[estimate]
    block_frames``."""
    return link_rate(config) / config.estimate.block_frames


def wire_check_of(link):
    """The range check of ``link``'s load command for the gate: a link with a DBC wire
    profile (the CAN links) has one (:func:`firmware_bridge.protocol.payload_wire_error`);
    others (serial msgpack floats, pylibfranka) have no ranges to check: None."""
    from firmware_bridge.protocol import WireProfile, payload_wire_error

    wire = getattr(link, "profile", None)
    if not isinstance(wire, WireProfile):
        return None
    return functools.partial(payload_wire_error, profile=wire.name)


def load_or_train_model(config: CellConfig):
    """The model of the configuration: its file, or a new one trained on the excitation path."""
    mc = config.model
    path = FsPath(mc.path)
    for stale in remove_stale_temporaries(path):  # left by a save that was killed
        log.info("removed %s, the temporary file of an interrupted save", stale,
                 extra={"event": "stale_temporary_removed", "path": str(stale)})
    rate, frames = link_rate(config), config.estimate.block_frames
    if path.exists():
        model = load_model(path)
        made_for = getattr(model, "rate_hz", rate / frames)  # IEM+phys's filters have one
        if not math.isclose(made_for, rate / frames):
            from .config import ConfigError

            raise ConfigError(
                f"model file {path} was made for {made_for:g} block points per second; the "
                f"[link] profile {config.link.profile!r} delivers {rate:g} joint states per "
                f"second, in blocks of [estimate] block_frames = {frames}: "
                f"{rate / frames:g}; make one for this link with 'iem train --out {path} "
                f"--rate {rate:g} --block-frames {frames}'")
        log.info("loaded model %s: %s with %d bags", path, model.name, model.n_bags,
                 extra={"event": "model_loaded", "path": str(path), "bags": model.n_bags})
        if model.name != mc.kind:
            log.warning("model file %s holds a %s model, the configuration asks for %s; using "
                        "the file's", path, model.name, mc.kind)
        return model
    if not mc.train_if_missing:
        from iem.errors import ModelFileError

        raise ModelFileError(f"model file {path} does not exist and [model] train_if_missing "
                             "is false; create one with 'iem train --out FILE' or set "
                             "train_if_missing = true")
    from .training import train_initial_model

    model = train_initial_model(mc.kind, mc.family, mc.excitation, mc.seed,
                                log=lambda msg: log.info(msg, extra={"event": "trained"}),
                                rate_hz=rate, block_frames=frames, arm_file=mc.arm or None,
                                end_effector=config.arm.end_effector, noise=config.arm.noise)
    path.parent.mkdir(parents=True, exist_ok=True)
    save_model(model, path)
    log.info("saved the new model to %s", path, extra={"event": "model_saved"})
    return model


INITIAL_STD = (0.01, 0.002, 0.002, 0.002, 0.002, 0.002, 0.002, 0.002, 0.002, 0.002)
"""The prior's standard deviations of an initial payload file without ``phi_std`` (kg, kg·m,
kg·m²): what an offline identification on a short motion reaches at least."""


def start_from_file(model, path: str) -> None:
    """Make ``model`` start from the payload file at ``path`` (``[estimate]
    initial_payload``): its first estimate and prior."""
    from sim.payload import load_payload_prior

    from .config import ConfigError

    start = getattr(model, "start_from", None)
    if start is None:
        raise ConfigError(f"[estimate] initial_payload = {path!r}: the {model.name} model "
                          "cannot start from a payload (it keeps no payload state); valid "
                          "with [model] kind = 'IEM+phys'")
    payload, std = load_payload_prior(path)
    start(payload.to_phi(), INITIAL_STD if std is None else std)
    log.info("starting from the payload file %s: %.4f kg at [%.4f, %.4f, %.4f] m; writes wait "
             "until the live data have tested it", path, payload.mass, *payload.com,
             extra={"event": "initial_payload", "path": path})


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
        threaded_reader: read the link in a thread of its own (:class:`deploy.reader.
            LinkReader`), so reading never waits for estimating; else in bulk in the loop's
            thread (:class:`deploy.reader.BatchReader`). None: threaded for a live link
            (``gate_clock`` monotonic), not for a replay, which must lose nothing and run as
            fast as the estimator goes.
    """

    def __init__(self, config: CellConfig, link=None, model=None,
                 notifier: Notifier | None = None, status: StatusLine | None = None,
                 write: bool = True, gate_clock: str = "monotonic",
                 threaded_reader: bool | None = None) -> None:
        if gate_clock not in ("monotonic", "controller"):
            raise ValueError(f"gate_clock {gate_clock!r}; valid are 'monotonic', 'controller'")
        self.gate_clock = gate_clock
        self.threaded_reader = (gate_clock == "monotonic" if threaded_reader is None
                                else bool(threaded_reader))
        self.config = config
        self.link = link
        self.model = model
        self.notifier = Notifier() if notifier is None else notifier
        self.status = status if status is not None else StatusLine.from_config(config.log)
        self.write = write
        self.gate = SafetyGate(config.gate)
        self.arm_watch = ArmWatch()
        """Says once when the mass stays clearly below zero (a wrong arm model)."""
        self.checkpointer = Checkpointer(config.model.path, config.model.checkpoint_period_s)
        self.writer: LoadWriter | None = None
        self.on_cycle: list[Callable[[CycleRecord], None]] = []
        self._stop = threading.Event()
        self.latencies = LatencyWindow()
        """Block-to-estimate latencies: from a block's last frame's arrival to its estimate."""
        self.ages = LatencyWindow()
        """Age of a block's frames (their mean arrival) when its estimate is out."""
        self.cycles = 0
        """Block points estimated."""
        self.silent = False
        self.silences = 0
        self.skipped = 0
        self.reader_skipped = 0
        self.unlearnt = 0
        self._behind = False
        self.cpu_s = 0.0
        self.cpu_parts = {"cycle": 0.0, "reader": 0.0, "learning": 0.0, "checkpoint": 0.0}
        """CPU s of the last run by thread: the estimating loop's, the link reader's, the
        learning worker's and the checkpoints' (``cpu_s`` is their sum)."""
        self.wall_s = 0.0
        self.cpu_latency = None
        """The held CPU wake-up latency limit (``[host] cpu_dma_latency_us``), or None."""

    @property
    def checkpoints(self) -> int:
        """Saves of the model so far."""
        return self.checkpointer.count

    # -- set-up ----------------------------------------------------------------------------
    def open(self) -> Service:
        from sim.robot import PandaModel

        from .host import hold_cpu_latency
        from .training import check_model_arm, check_model_family, load_arm_file, tandem_for

        if self.cpu_latency is None:  # first: a host that refuses it fails before training
            self.cpu_latency = hold_cpu_latency(self.config.host.cpu_dma_latency_us)
            if self.cpu_latency is not None:
                log.info("holding a CPU wake-up latency limit of %d µs on %s (in force: %d "
                         "µs)", self.cpu_latency.latency_us, self.cpu_latency.device,
                         self.cpu_latency.effective_us, extra={"event": "cpu_latency"})
        arm, arm_record = load_arm_file(self.config.model.arm or None,
                                        self.config.arm.end_effector)
        if self.model is None:
            self.model = load_or_train_model(self.config)
        path = FsPath(self.config.model.path)
        check_model_arm(self.model, arm_record,
                        where=f"the model {path}" if path.exists() else "the model")
        check_model_family(self.model, self.config.model.family,
                           where=f"the model {path}" if path.exists() else "the model")
        if self.config.estimate.initial_payload:
            start_from_file(self.model, self.config.estimate.initial_payload)
        # a live link: learning and heavy work never hold up estimating; a replay: inline
        # and at once, reproducible
        self.model.go_live(self.threaded_reader,
                           background=self.config.estimate.background_learning)
        if self.link is None:
            from firmware_bridge.links import open_link

            lc = self.config.link
            self.link = open_link(lc.kind, lc.channel, profile=lc.profile,
                                  silence_timeout=lc.silence_timeout_s,
                                  **self.config.link_options())  # [ros2] for kind ros2
        est = self.config.estimate
        self.rate_hz = link_rate(self.config)
        self.point_rate_hz = self.rate_hz / est.block_frames
        self.kinematics = PandaModel()
        self.tandem = tandem_for(self.config.model.family, arm)
        self.online = OnlineIdentifier(
            self.model, self.kinematics.flange_position, self.tandem.samples,
            learn=est.learn,
            state_filter=StateFilter(min(est.filter_cutoff_hz, 0.45 * self.point_rate_hz),
                                     self.point_rate_hz),
            smoother=ExponentialSmoother(tau_s=est.smoothing_tau_s,
                                         dt=1.0 / self.point_rate_hz),
            former=self._former())
        self.gate.wire_check = wire_check_of(self.link)  # out_of_wire_range before send
        return self

    def _former(self) -> BlockFormer:
        return BlockFormer(self.config.estimate.block_frames, self.rate_hz)

    def stop(self) -> None:
        """Ask the loop to end after the current block (safe from a signal handler)."""
        self._stop.set()

    @property
    def stopping(self) -> bool:
        return self._stop.is_set()

    # -- the loop --------------------------------------------------------------------------
    def run(self, duration: float | None = None,
            until: Callable[[], bool] | None = None) -> dict:
        """Run until stopped, ``duration`` s passed, ``until()`` is true or a replay ends."""
        from .reader import BatchReader, LinkReader

        if self.link is None or self.model is None:
            self.open()
        cfg, model = self.config, self.model
        self.writer = LoadWriter(self.gate, self.link, self.write)  # the link as it is now
        started = time.monotonic()
        cpu0 = time.thread_time()
        learn0 = model.learning_cpu_s
        save0 = self.checkpointer.cpu_s
        self.checkpointer.start(started)
        watchdog = self.notifier.watchdog_period()
        next_watchdog = started
        self.notifier.ready(f"identifying the payload; {model.n_bags} bags")
        log.info("running: link %s, model %s (%d bags), writes %s, %g block points per s",
                 getattr(self.link, "name", self.link), model.name, model.n_bags,
                 "on" if self.writer.sink is not None else "off", self.point_rate_hz,
                 extra={"event": "started"})
        timeout = cfg.link.silence_timeout_s
        reader = (LinkReader if self.threaded_reader else BatchReader)(
            self.link, timeout, self._former()).start()
        smoothed = None
        try:
            while not self._stop.is_set():
                now = time.monotonic()
                if duration is not None and now - started >= duration:
                    break
                if until is not None and until():
                    break
                if watchdog is not None and now >= next_watchdog:
                    self.notifier.watchdog()
                    next_watchdog = now + watchdog
                item = reader.get(timeout + 0.5)
                if item is None:
                    continue
                if item.kind == "silent":
                    self._controller_silent(item.value)
                    if smoothed is not None:  # the gate decides (and counts) on no write
                        self.gate.decide(time.monotonic(), smoothed)
                    continue
                if item.kind == "end":
                    break
                if item.kind == "error":
                    raise item.value
                out = self.step(item)
                if out is None:
                    continue
                smoothed = out.smoothed
                now = time.monotonic()
                t_gate = out.state.t if self.gate_clock == "controller" else now
                self.writer.observe(t_gate, smoothed, out.raw, model.busy)
                self.checkpointer.tick(now, model)
                if self.status.due(now):
                    self.status.show(self._status_text(now - started, smoothed))
        finally:
            self.wall_s = time.monotonic() - started
            reader.stop()
            self.reader_skipped += reader.skipped
            parts = self.cpu_parts = {"cycle": time.thread_time() - cpu0,
                                      "reader": reader.cpu_s if self.threaded_reader else 0.0,
                                      "learning": model.learning_cpu_s - learn0,
                                      "checkpoint": self.checkpointer.cpu_s - save0}
            self.cpu_s = sum(parts.values())
            self.status.clear()
            self.notifier.stopping()
        return self.summary()

    def step(self, item) -> CycleRecord | None:
        """One block point through the estimator (no thread of its own): pace against the
        controller on a live link, learn and estimate, publish, record the latency, watch
        the arm model, tell the observers. None: the point was dropped (hopelessly late)."""
        state = item.value
        if self.silent:
            self._controller_back()
        arrived = item.frame_time  # the block's last frame's arrival (epoch s)
        max_lag = self.config.estimate.max_lag_s if self.gate_clock == "monotonic" else 0.0
        if max_lag:
            lag = time.time() - arrived if arrived > 0 else 0.0
            if lag > SKIP_LAG_S:
                self.skipped += 1  # hopelessly behind: drop the point
                return None
            self._pace(lag, max_lag)
        raw, smoothed = self.online.step_block(state)
        publish = getattr(self.link, "publish_estimate", None)
        if publish is not None:  # the ros2 link: the estimate on its topics, at its own rate
            publish(raw, smoothed)
        done = time.time()
        latency = done - arrived if arrived > 0 else math.nan
        age = (done - 0.5 * (arrived + item.first_time) if arrived > 0 and item.first_time > 0
               else math.nan)
        self.latencies.add(latency)
        self.ages.add(age)
        self.cycles += 1
        self.arm_watch.observe(state.t, smoothed, raw)
        record = CycleRecord(state, raw, smoothed, latency, age)
        for observer in self.on_cycle:
            observer(record)
        return record

    def close(self) -> None:
        """Final checkpoint (synchronous: the learning worker's pending work lands first),
        then stop the worker and close the link."""
        try:
            if self.model is not None:
                self.checkpoint()
        finally:
            if self.cpu_latency is not None:  # first: the loop is over, and a failing
                self.cpu_latency.close()  # worker or link must not keep cores polling
                self.cpu_latency = None
            if self.model is not None:
                self.model.stop()
            if self.link is not None:
                self.link.close()
            self.notifier.close()

    def checkpoint(self) -> None:
        """Save the model now (atomic), waiting for a background save first."""
        self.checkpointer.save_now(self.model)

    # -- events ----------------------------------------------------------------------------
    def _controller_silent(self, why: str) -> None:
        if not self.silent:
            self.silent = True
            self.silences += 1
            self.gate.controller_silent(True)
            log.warning("controller silent: writes stopped (%s)", why,
                        extra={"event": "controller_silent"})
            self.notifier.status("controller silent: writes stopped")
        self.status.show("controller silent: writes stopped", force=True)

    def _pace(self, lag: float, max_lag: float) -> None:
        """Behind the controller by more than ``max_lag`` s (a slow learning step), the
        service still estimates every point but skips the learning steps until it is
        current again (below half of ``max_lag``), so estimates and writes stay fresh;
        counted in ``unlearnt``, logged once per episode."""
        behind = lag > (max_lag / 2.0 if self._behind else max_lag)  # hysteresis
        if behind:
            self.unlearnt += 1
        if behind != self._behind:
            self._behind = behind
            self.online.learn = self.config.estimate.learn and not behind
            if behind:
                log.warning("behind the controller by %.0f ms: estimating without learning "
                            "until current", lag * 1e3, extra={"event": "behind",
                                                               "lag_ms": lag * 1e3})
            else:
                log.info("current again (%d points estimated without learning so far)",
                         self.unlearnt, extra={"event": "current",
                                               "unlearnt": self.unlearnt})

    def _controller_back(self) -> None:
        self.silent = False
        self.gate.controller_silent(False)
        self.online.resume()  # the signal was interrupted; the payload estimate stays
        log.info("controller back: writes resume", extra={"event": "controller_back"})
        self.notifier.status("identifying the payload")

    # -- reporting -----------------------------------------------------------------------
    def _status_text(self, elapsed: float, phi: np.ndarray) -> str:
        c = self.link.counters
        rate = self.cycles / elapsed if elapsed > 0 else 0.0
        m = phi[0]
        com = phi[1:4] / m if m > 0 else np.full(3, np.nan)
        drops = sum(c.dropped().values())
        return (f"{elapsed:6.1f} s  m {m:6.3f} kg  c [{com[0]:+.3f} {com[1]:+.3f} "
                f"{com[2]:+.3f}] m  bags {self.model.n_bags}  {rate:6.0f} est/s  writes "
                f"{self.gate.sent}/{self.gate.acked}"
                + (f" refused {self.gate.refusals}" if self.gate.refusals else "")
                + f"  drops {drops} lost {c.lost}"
                + ("  SILENT" if self.silent else ""))

    def summary(self) -> dict:
        c = self.link.counters
        gate = self.gate.summary()
        return {
            "cycles": self.cycles,
            "estimates": self.cycles,
            "bags": self.model.n_bags,
            "model": self.model.name,
            "block_frames": self.config.estimate.block_frames,
            "latency_us": dict(zip(("p50", "p99"), self.latencies.percentiles_us(50, 99),
                                   strict=True)),
            "age_us": dict(zip(("p50", "p99"), self.ages.percentiles_us(50, 99),
                               strict=True)),
            "writes": {"sent": gate["sent"], "acked": gate["acked"],
                       "rejected": gate["rejected"], "refused_by_controller": self.gate.refusals,
                       "send_errors": self.gate.send_errors},
            "frames": {"received": c.received, "dropped": c.dropped(), "lost": c.lost,
                       "skipped": self.skipped + self.reader_skipped,
                       "not_newer": self.online.skipped},
            "unlearnt": self.unlearnt,
            "learnt": self.online.learned_points,
            "gate": gate["decisions"],
            "silences": self.silences,
            "arm_mismatch": self.arm_watch.finding,
            "checkpoints": self.checkpoints,
            "wall_s": self.wall_s,
            "cpu_s": self.cpu_s,
            "cpu_parts": dict(self.cpu_parts),
            "cpu_dma_latency_us": (None if self.cpu_latency is None
                                   else self.cpu_latency.latency_us),
        }


def configure(parser) -> None:
    parser.add_argument("--config", required=True, metavar="FILE", help="cell.toml")
    parser.add_argument("--duration", type=float, help="stop after this many s")


def run(args) -> int:
    import signal

    from .config import load_config
    from .logs import setup_logging

    config = load_config(args.config)
    setup_logging(config.log.level, config.log.format)
    service = Service(config)
    signal.signal(signal.SIGTERM, lambda *_: service.stop())
    signal.signal(signal.SIGINT, lambda *_: service.stop())
    try:
        service.open()
        summary = service.run(duration=args.duration)
    finally:
        service.close()
    log.info("stopped: %s", summary, extra={"event": "stopped"})
    print(f"iem run: {summary['cycles']} cycles, {summary['bags']} bags, writes "
          f"{summary['writes']}", file=sys.stderr)
    return 0
