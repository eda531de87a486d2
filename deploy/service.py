"""The plug-in service: joint states in, identified payload out (``iem run``).

One loop, one thread: the link's ``read`` gives the next controller cycle;
:class:`iem.online.OnlineIdentifier` learns from it (new bags are trained with the tandem
simulators of the configured payload family) and estimates; the smoothed estimate goes to
the :class:`deploy.gate.SafetyGate` (with the raw estimate, for its uncertainty, and the
link's wire range check, :func:`wire_check_of`), and a load it lets through goes to the
link's ``send`` (libfranka ``setLoad`` semantics); a load the link still cannot encode
(``EncodeError``) is counted and logged, never fatal. Acknowledgements come back through the
link: an applied one to the gate's ``acknowledged``, a refusal (``applied=False``, with the
controller's ``error`` text where the link has one) to its ``refused``, which retries later.

Around the loop: temporary files of an interrupted save are removed at start
(:func:`iem.persistence.remove_stale_temporaries`); the model is loaded (or trained if there
is none and ``train_if_missing``), saved every ``checkpoint_period_s`` and at exit
(atomically: a failed save leaves the last good file; the periodic save runs in a background
thread on a copy); a silent controller stops the writes until it returns; link failures end
the run with the error (exit status 2: under systemd, the unit restarts it; configuration
errors exit 78 and are not restarted, see :mod:`deploy.cli`). ``Service.stop()`` (SIGTERM,
SIGINT) ends the loop after the current cycle.
"""

from __future__ import annotations

import copy
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

from iem.filters import StateFilter
from iem.online import OnlineIdentifier
from iem.persistence import load_model, remove_stale_temporaries, save_model
from iem.smoothing import ExponentialSmoother

from .arm_watch import ArmWatch
from .config import CellConfig
from .gate import SafetyGate
from .latency import LatencyWindow
from .sdnotify import Notifier
from .status import StatusLine

log = logging.getLogger("iem.service")

GATE_DEFER = 3
"""Cycles a due gate decision may wait for one in which the model did no heavy work (about
0.2 ms of a decision then does not land on top of a refresh or an equation: the latency's
p99 is the cycles that do both)."""
SKIP_LAG_S = 2.0
"""A cycle older than this when read is dropped (counted in ``skipped``): even estimating
without learning has fallen hopelessly behind."""


@dataclass
class CycleRecord:
    """What the service made of one cycle (given to ``on_cycle`` observers)."""

    state: object
    raw: object
    smoothed: np.ndarray
    latency_s: float


def link_rate(config: CellConfig) -> float:
    """Joint states per second the configured link delivers, as its kind and wire profile say
    (:func:`firmware_bridge.links.rate_hz`)."""
    from firmware_bridge.links import rate_hz

    return rate_hz(config.link.kind, config.link.profile)


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
    rate = link_rate(config)
    if path.exists():
        model = load_model(path)
        made_for = getattr(model, "rate_hz", rate)
        if made_for != rate:
            from .config import ConfigError

            raise ConfigError(
                f"model file {path} was made for {made_for:g} joint states per second, the "
                f"[link] profile {config.link.profile!r} delivers {rate:g}; make one for this "
                f"link with 'iem train --out {path} --rate {rate:g}'")
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
                                rate_hz=rate, arm_file=mc.arm or None,
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
    """The running plug-in.

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
        threaded_reader: read the link in a thread of its own (:mod:`deploy.reader`), so
            reading never waits for estimating; None: for a live link (``gate_clock``
            monotonic), not for a replay, which must lose nothing and run as fast as the
            estimator goes.
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
        self.on_cycle: list[Callable[[CycleRecord], None]] = []
        self._stop = threading.Event()
        self._saver: threading.Thread | None = None
        self.latencies = LatencyWindow()
        self.cycles = 0
        self.silent = False
        self.silences = 0
        self.skipped = 0
        self.reader_skipped = 0
        self.unlearnt = 0
        self._behind = False
        self.checkpoints = 0
        self.cpu_s = 0.0
        self.cpu_parts = {"cycle": 0.0, "reader": 0.0, "learning": 0.0, "checkpoint": 0.0}
        """CPU s of the last run by thread: the cycle's, the link reader's, the learning
        worker's and the checkpoints' (``cpu_s`` is their sum)."""
        self._checkpoint_cpu_s = 0.0
        self.wall_s = 0.0
        self.cpu_latency = None
        """The held CPU wake-up latency limit (``[host] cpu_dma_latency_us``), or None."""

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
        self.kinematics = PandaModel()
        self.tandem = tandem_for(self.config.model.family, arm)
        self.online = OnlineIdentifier(
            self.model, self.kinematics.flange_position, self.tandem.samples,
            learn=est.learn,
            state_filter=StateFilter(cutoff_hz=min(est.filter_cutoff_hz, 0.45 * self.rate_hz),
                                     rate_hz=self.rate_hz),
            smoother=ExponentialSmoother(tau_s=est.smoothing_tau_s, dt=1.0 / self.rate_hz))
        self.gate.wire_check = wire_check_of(self.link)  # out_of_wire_range before send
        return self

    def stop(self) -> None:
        """Ask the loop to end after the current cycle (safe from a signal handler)."""
        self._stop.set()

    @property
    def stopping(self) -> bool:
        return self._stop.is_set()

    # -- the loop --------------------------------------------------------------------------
    def run(self, duration: float | None = None,
            until: Callable[[], bool] | None = None) -> dict:
        """Run until stopped, ``duration`` s passed, ``until()`` is true or a replay ends."""
        from firmware_bridge.errors import ControllerSilent, EncodeError, EndOfStream

        from .reader import Item, LinkReader

        if self.link is None or self.model is None:
            self.open()
        cfg = self.config
        link, online, gate = self.link, self.online, self.gate
        sink = self.write and hasattr(link, "send")
        publish = getattr(link, "publish_estimate", None)
        started = time.monotonic()
        cpu0 = time.thread_time()
        model = self.model
        learn0 = model.learning_cpu_s
        save0 = self._checkpoint_cpu_s
        next_checkpoint = started + cfg.model.checkpoint_period_s
        watchdog = self.notifier.watchdog_period()
        next_watchdog = started
        last_ack = None
        last_smoothed = None
        controller_clock = self.gate_clock == "controller"
        max_lag = cfg.estimate.max_lag_s if self.gate_clock == "monotonic" else 0.0
        self.notifier.ready(f"identifying the payload; {self.model.n_bags} bags")
        log.info("running: link %s, model %s (%d bags), writes %s", getattr(link, "name", link),
                 self.model.name, self.model.n_bags, "on" if sink else "off",
                 extra={"event": "started"})
        reader = (LinkReader(link, cfg.link.silence_timeout_s).start() if self.threaded_reader
                  else None)
        deferred = 0

        def next_item() -> Item | None:
            if reader is not None:
                return reader.get(cfg.link.silence_timeout_s + 0.5)
            try:
                state = link.read(cfg.link.silence_timeout_s)
            except ControllerSilent as exc:
                return Item("silent", str(exc))
            except EndOfStream:
                return Item("end")
            return Item("state", state, getattr(link, "last_frame_time", 0.0))

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
                item = next_item()
                if item is None:
                    continue
                if item.kind == "silent":
                    self._controller_silent(item.value)
                    if last_smoothed is not None:  # the gate decides (and counts) on
                        gate.decide(time.monotonic(), last_smoothed)  # no write
                    continue
                if item.kind == "end":
                    break
                if item.kind == "error":
                    raise item.value
                state = item.value
                if self.silent:
                    self._controller_back()
                frame_t = item.frame_time  # its receive time (epoch s)
                if max_lag:
                    lag = time.time() - frame_t if frame_t > 0 else 0.0
                    if lag > SKIP_LAG_S:
                        self.skipped += 1  # hopelessly behind: drop the cycle
                        continue
                    self._pace(lag, max_lag)
                raw, smoothed = online.step(state)
                last_smoothed = smoothed
                if publish is not None:  # the ros2 link: the estimate on its topics,
                    publish(raw, smoothed)  # at its own rate
                latency = time.time() - frame_t if frame_t > 0 else math.nan
                self.latencies.add(latency)
                self.cycles += 1
                if self.on_cycle:
                    record = CycleRecord(state, raw, smoothed, latency)
                    for observer in self.on_cycle:
                        observer(record)
                now = time.monotonic()
                t_gate = state.t if controller_clock else now
                ack = getattr(link, "last_ack", None)
                if ack is not None and ack is not last_ack:
                    last_ack = ack
                    self._acknowledged(ack, t_gate)
                gate.observe(t_gate, smoothed, raw)
                self.arm_watch.observe(state.t, smoothed, raw)
                due = gate.due(t_gate)
                if due and model.busy and deferred < GATE_DEFER:
                    deferred += 1  # the model did its heavy job this cycle: decide in the
                elif due:  # next one (the cycles' work stays level)
                    deferred = 0
                    decision = gate.decide(t_gate, smoothed)
                    if decision.send and sink:
                        try:
                            seq = link.send(decision.payload)
                        except EncodeError as exc:  # the gate's wire check should have
                            gate.send_failed(str(exc))  # caught it: counted, logged, go on
                        else:
                            gate.sent_command(seq, t_gate)
                            log.info("load sent (command %d): %s", seq, decision.detail,
                                     extra={"event": "load_sent", "seq": seq})
                if now >= next_checkpoint:
                    self._checkpoint_async()
                    next_checkpoint = now + cfg.model.checkpoint_period_s
                if self.status.due(now):
                    self.status.show(self._status_text(now - started, smoothed))
        finally:
            self.wall_s = time.monotonic() - started
            parts = self.cpu_parts = {"cycle": time.thread_time() - cpu0, "reader": 0.0,
                                      "learning": model.learning_cpu_s - learn0,
                                      "checkpoint": self._checkpoint_cpu_s - save0}
            if reader is not None:
                reader.stop()
                self.reader_skipped += reader.skipped
                parts["reader"] = reader.cpu_s
            self.cpu_s = sum(parts.values())
            self.status.clear()
            self.notifier.stopping()
        return self.summary()

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
        service still estimates every cycle but skips the learning steps until it is
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
                log.info("current again (%d cycles estimated without learning so far)",
                         self.unlearnt, extra={"event": "current",
                                               "unlearnt": self.unlearnt})

    def _controller_back(self) -> None:
        self.silent = False
        self.gate.controller_silent(False)
        self.online.resume()  # the signal was interrupted; the payload estimate stays
        log.info("controller back: writes resume", extra={"event": "controller_back"})
        self.notifier.status("identifying the payload")

    def _acknowledged(self, ack, t: float) -> None:
        """An answer to a load command: applied, or refused (the gate counts and logs the
        refusal with the controller's error text and retries later)."""
        if ack.applied:
            self.gate.acknowledged(ack.seq)
            log.info("controller acknowledged load command %d", ack.seq,
                     extra={"event": "load_acked", "seq": ack.seq})
        else:
            self.gate.refused(ack.seq, t, str(getattr(ack, "error", "") or ""))

    # -- checkpoints ---------------------------------------------------------------------
    def checkpoint(self) -> None:
        """Save the model now (atomic), waiting for a background save first."""
        if self._saver is not None:
            self._saver.join()
        save_model(self.model, self.config.model.path)
        self.checkpoints += 1
        log.info("model saved to %s (%d bags)", self.config.model.path, self.model.n_bags,
                 extra={"event": "checkpoint", "bags": self.model.n_bags})

    def _checkpoint_async(self) -> None:
        if self._saver is not None and self._saver.is_alive():
            return  # the previous save is still writing; the next period catches up
        snapshot = copy.deepcopy(self.model)
        path = self.config.model.path

        def save() -> None:
            cpu0 = time.thread_time()
            try:
                save_model(snapshot, path)
                self.checkpoints += 1
                log.info("checkpoint: model saved to %s (%d bags)", path, snapshot.n_bags,
                         extra={"event": "checkpoint", "bags": snapshot.n_bags})
            except Exception:  # a failed save keeps the last good file; say so and go on
                log.exception("checkpoint to %s failed; the previous file is kept", path)
            finally:
                self._checkpoint_cpu_s += time.thread_time() - cpu0

        self._saver = threading.Thread(target=save, name="iem-checkpoint", daemon=True)
        self._saver.start()

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
            "latency_us": dict(zip(("p50", "p99"), self.latencies.percentiles_us(50, 99),
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
