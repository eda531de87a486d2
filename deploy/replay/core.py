"""``iem replay``: the plug-in over recorded traffic, as fast as the machine goes.

The recording is a CAN log (``.blf``, ``.log``, ``.asc``, ``.trc``, as ``iem record`` writes
them; ``--profile`` its wire profile), decoded by :class:`firmware_bridge.replay.ReplaySource`
exactly as the live link decodes the bus, or a rosbag2 bag of ``sensor_msgs/msg/JointState``
(``ros2 bag record /franka/joint_states``: its directory, a ``.db3`` or a ``.mcap``;
``--topic``) or a joint-state CSV (``t,q1..q7,dq1..dq7,tau1..tau7``), read by
:mod:`firmware_bridge.recordings` (``--format can|rosbag2|csv``, default: detected). Its joint
states are fed to the same :class:`deploy.service.loop.Service` that ``iem run`` uses, with writes
off: nothing is sent, but the safety gate still decides on every estimate, so the report says
what the plug-in would have written. The gate runs on the recorded controller clock (the joint
states' ``t``), not on the wall clock, so its decisions do not depend on how fast the replay
runs; a replay has no silences (a gap in the recording is just a gap).

The model is the one of ``--model FILE`` (loaded with the arm that ``--arm`` and
``--end-effector`` give: a model file references its arm by content, never by path) or, by
default, a fresh model of the default kind (:data:`iem.model_kinds.DEFAULT_MODEL`,
IEM+phys) trained on the built-in excitation path with seed 0 for the recording's rate and
``--block-frames``. Either way the
replay learns in memory only: the file is never written unless ``--save-model FILE`` asks
for it. Decoding, training and learning are deterministic, so replaying the same file twice
gives identical estimates (``--out``).

The recording's rate is ``--rate HZ`` or else detected (:mod:`iem.signals.rate`), printed; the
estimator works on block points, the means of ``--block-frames`` consecutive joint states (by
default ``round(rate / 100)``, :mod:`iem.signals.blocks`), a ``--model`` made for another point
rate refused. The recording is read in bulk and its blocks formed in one vectorised step per
chunk, then fed as fast as the estimator takes them, learning inline (the JSON's ``speed`` is
the recorded time over the wall time).

Outputs: ``--out`` a CSV with one row per estimate, one per block point (``t``, the block's
mean time, ``cycle``, its last frame's, ``bag``, the raw ``m..Izz``, the
smoothed ``m_s..Izz_s`` and the raw estimate's standard deviations ``m_std..Izz_std``, the
paper's parameter order, kg, kg·m, kg·m²; ``nan`` where the model gives none); ``--truth``
the MAE of the smoothed estimates against a payload file by group (``mae_groups``) and the
share of the raw estimates within two standard deviations of it (``coverage_2sigma``);
``--json`` the summary, whose ``writes.would_send_loads`` lists each load the gate would have
written (``t``, ``mass``, ``com``, ``inertia`` about the CoM, ``from_prior``) and whose
``arm_mismatch`` says when the mass stayed clearly below zero (:mod:`deploy.service.arm_watch`).
A missing, unknown or unreadable recording, a CAN log without a single complete cycle of the
given profile, or a bag or CSV with a missing joint or column, a non-finite value or time
stamps that do not increase, is a :class:`firmware_bridge.errors.LogFileError` (``iem``: exit
status 2). A damaged CAN log loses only what is damaged: a truncated one replays what it holds
and says so on stderr and in the summary (``"truncated": true``); a bad line of a ``.log``,
``.asc`` or ``.trc`` is skipped and counted (``frames.malformed``).

A folder of recordings, a glob or several paths replay each recording on its own, in
``--jobs`` processes, then print a table over all: :mod:`deploy.replay.many`.
"""

from __future__ import annotations

import copy
from pathlib import Path as FsPath

import numpy as np

from firmware_bridge.protocol import PROFILES
from firmware_bridge.recordings import DEFAULT_TOPIC
from iem.errors import InvalidInputError
from iem.model_kinds import DEFAULT_MODEL
from iem.types import PARAMS

from .report import add_replay_figures

CSV_HEADER = ("t", "cycle", "bag", *PARAMS, *(f"{p}_s" for p in PARAMS),
              *(f"{p}_std" for p in PARAMS))
"""Columns of ``--out``: controller time (s), cycle, bag, raw then smoothed phi, then the raw
estimate's standard deviations (``nan`` where the model gives none)."""

_NO_STD = np.full(len(PARAMS), np.nan)
_NO_STD.flags.writeable = False


class Estimates:
    """The estimates of a replay, one row per block point (an ``on_cycle`` observer)."""

    def __init__(self) -> None:
        self.t: list[float] = []
        self.cycle: list[int] = []
        self.bag: list[int] = []
        self.raw: list[np.ndarray] = []
        self.smoothed: list[np.ndarray] = []
        self.std: list[np.ndarray] = []

    def __call__(self, record) -> None:
        self.t.append(float(record.state.t))
        self.cycle.append(int(record.state.cycle))
        self.bag.append(int(record.raw.bag))
        self.raw.append(np.array(record.raw.phi, dtype=float))
        self.smoothed.append(np.array(record.smoothed, dtype=float))
        std = record.raw.std
        self.std.append(_NO_STD if std is None else np.array(std, dtype=float))

    def __len__(self) -> int:
        return len(self.t)

    def smoothed_array(self) -> np.ndarray:
        return np.array(self.smoothed).reshape(-1, len(PARAMS))

    def coverage_2sigma(self, phi) -> dict[str, float | None]:
        """Per group of :data:`iem.types.GROUPS`: the share of the raw estimates' parameters
        within two of their standard deviations of ``phi`` (None: the model gives none)."""
        from iem.types import GROUPS

        raw = np.array(self.raw).reshape(-1, len(PARAMS))
        std = np.array(self.std).reshape(-1, len(PARAMS))
        has = np.isfinite(std).all(axis=1) & np.isfinite(raw).all(axis=1)
        if not has.any():
            return {g: None for g in GROUPS}
        inside = np.abs(raw[has] - np.asarray(phi)) <= 2.0 * std[has]
        return {g: float(inside[:, list(idx)].mean()) for g, idx in GROUPS.items()}

    def csv_text(self) -> str:
        """The CSV (exact: every float as its shortest round-trip repr)."""
        lines = [",".join(CSV_HEADER)]
        for t, cycle, bag, raw, sm, sd in zip(self.t, self.cycle, self.bag, self.raw,
                                              self.smoothed, self.std, strict=True):
            lines.append(",".join([repr(t), str(cycle), str(bag), *map(repr, raw.tolist()),
                                   *map(repr, sm.tolist()), *map(repr, sd.tolist())]))
        return "\n".join(lines) + "\n"

    def write_csv(self, path) -> None:
        write_output(path, self.csv_text())


def write_output(path, text: str) -> None:
    """Write ``text`` to ``path`` (an output of ``iem replay``); InvalidInputError naming it."""
    try:
        FsPath(path).write_text(text, encoding="utf-8")
    except OSError as exc:
        raise InvalidInputError(f"{path}: cannot write: {exc.strerror or exc}") from exc


def replay(log_file, *, profile: str = "fd", model=None, truth=None, save_model_to=None,
           status: bool = False, log=print, arm_file=None, format: str | None = None,
           topic: str = DEFAULT_TOPIC, end_effector=None,
           block_frames: int | None = None,
           rate_hz: float | None = None, description=None,
           rated_mass_kg: float | None = None) -> tuple[dict, Estimates]:
    """Run the plug-in over ``log_file`` as fast as possible, writes off.

    Args:
        log_file: the recording: a ``.blf``, ``.log``, ``.asc`` or ``.trc`` CAN log, a
            rosbag2 bag (directory, ``.db3``, ``.mcap``) or a joint-state CSV.
        profile: the wire profile a CAN log was recorded with (``fd`` or ``classic``).
        model: the estimator to start from (copied, never changed); None: a fresh model
            of :data:`iem.model_kinds.DEFAULT_MODEL` trained on the built-in excitation
            path with seed 0, for the recording's rate and ``block_frames``.
        truth: a :class:`sim.payload.Payload` to compute the MAE against, or None.
        save_model_to: save the model learnt during the replay to this file (atomic).
        status: show the live status line on stderr.
        log: where progress lines go.
        arm_file: the arm file of the arm that was recorded (``iem calibrate``); the model
            must have been trained for it. None: the nominal arm.
        format: ``can``, ``rosbag2`` or ``csv``; None: detected from the file
            (:func:`firmware_bridge.recordings.detect_format`).
        topic: a rosbag2 bag's JointState topic.
        end_effector: what the recorded arm carried as part of itself
            (:mod:`sim.end_effector`; None: the Franka Hand); the arm file and the model
            must be made for it.
        block_frames: frames per block point (None:
            :func:`iem.signals.rate.block_frames_for` the rate: about 100 points a second);
            the model must be made for the same point rate.
        rate_hz: the recording's joint states a second (None: detected,
            :func:`firmware_bridge.recordings.can_log_rate` for a CAN log).
        description: the recorded arm's model (:mod:`sim.description`; an
            :class:`~sim.description.ArmDescription`, None: the default), whose joint names
            a rosbag2 bag must carry; the arm file and the model must be made for it.
        rated_mass_kg: its rated payload for the gate's verdicts (None: the arm model's).

    Returns:
        ``(summary, estimates)``: the summary dict (the keys of the demo's summary where
        they apply) and the per-cycle :class:`Estimates`.
    """
    from deploy.model.training import check_model_rate, train_initial_model
    from firmware_bridge.links import open_link
    from firmware_bridge.recordings import recording_link
    from iem.persistence import save_model
    from sim.description import described
    from sim.family import DEPLOY_FAMILY

    fmt, kind, options = recording_link(log_file, format, topic,
                                        described(description).joint_names)
    if fmt != "can":
        options["rate_hz"] = rate_hz
    link = open_link(kind, str(log_file), profile=profile, **options)
    try:
        rate, block_frames, detected = _rate_of(link, log_file, fmt, profile, rate_hz,
                                                block_frames, log)
        if model is None:
            model = train_initial_model(DEFAULT_MODEL, DEPLOY_FAMILY, "builtin", 0, log=log,
                                        rate_hz=rate, block_frames=block_frames,
                                        arm_file=arm_file, end_effector=end_effector,
                                        description=description)
        else:
            check_model_rate(model, rate, block_frames, f"the recording {log_file}")
            model = copy.deepcopy(model)
        service = _replay_service(link, kind, str(log_file), profile, model, save_model_to,
                                  arm_file, end_effector, block_frames, status, rate,
                                  description, rated_mass_kg)
        estimates = Estimates()
        service.on_cycle.append(estimates)
        service.open()
        summary = service.run()
        if save_model_to is not None:
            save_model(service.model, save_model_to)
            log(f"saved the learnt model ({service.model.n_bags} bags) to {save_model_to}")
    finally:
        link.close()

    if not estimates.t:  # nothing to report on: say why rather than print zeros
        _nothing_estimated(log_file, link, profile)
    add_replay_figures(summary, service, link, estimates,
                        {"log_file": str(log_file), "format": fmt,
                         "profile": profile if fmt == "can" else None, "rate_hz": rate,
                         "rate_source": "detected" if detected else "given"})
    if truth is not None:
        summary.update(_against(estimates, truth))
    return summary, estimates


def _rate_of(link, log_file, fmt: str, profile: str, rate_hz, block_frames, log):
    """``(rate, block_frames, detected)`` of the recording open as ``link`` (given or
    detected, checked; :mod:`iem.signals.rate`), the line saying so to ``log``."""
    from firmware_bridge.errors import LogFileError
    from firmware_bridge.recordings import can_log_rate
    from iem.signals.rate import block_frames_for, check_rate, rate_line

    detected = rate_hz is None
    try:
        if detected:
            rate_hz = can_log_rate(log_file, profile) if fmt == "can" else link.rate_hz
    except LogFileError:  # fewer than two cycles: the error that says why
        _ = [*link]
        _nothing_estimated(log_file, link, profile)
    rate = check_rate(rate_hz, f"the recording {log_file}")
    frames = int(block_frames) if block_frames else block_frames_for(rate)
    log(rate_line(rate, frames, detected))
    return rate, frames, detected


def _against(estimates: Estimates, truth) -> dict:
    """The estimates scored against the true payload: its name, the MAE of the smoothed
    estimate, the raw one's 2-sigma coverage, the final estimate beside the truth."""
    from iem.metrics import mae_groups

    sm = estimates.smoothed_array()
    return {"payload": truth.name, "mae_groups": mae_groups(sm, truth.to_phi()),
            "coverage_2sigma": estimates.coverage_2sigma(truth.to_phi()),
            "final_estimate": {"phi": sm[-1].tolist(), "truth": truth.to_phi().tolist()}}


def _replay_service(link, kind: str, channel: str, profile: str, model, save_model_to,
                    arm_file, end_effector, block_frames: int, status: bool, rate_hz: float,
                    description=None, rated_mass_kg: float | None = None):
    """The service over an open recording ``link`` of ``rate_hz`` joint states a second in
    blocks of ``block_frames``, writes off, deciding on the recorded clock (a fast replay
    decides as the cell did)."""
    from deploy.config import cell_config
    from deploy.service.loop import Service
    from deploy.service.sdnotify import Notifier
    from deploy.service.status import StatusLine
    from iem.persistence import DEFAULT_FAMILY
    from sim.description import described

    config = cell_config(
        described(description), rated_mass_kg, where="iem replay", status=status,
        link={"kind": kind, "channel": channel, "profile": profile},
        # the model path is only written by --save-model; no periodic checkpoints
        model={"path": str(save_model_to or "replay-model.msgpack"),
               "train_if_missing": False, "checkpoint_period_s": 86400.0,
               "arm": str(arm_file or ""),
               # the model's own family: new bags learn from the simulators it knew
               "family": model.trained_family or DEFAULT_FAMILY},
        arm={"end_effector": str(end_effector or "")},
        estimate={"block_frames": int(block_frames)})
    return Service(config, link=link, model=model, notifier=Notifier(environ={}),
                   status=StatusLine.from_config(config.log), write=False,
                   gate_clock="controller", rate_hz=rate_hz)


def _nothing_estimated(log_file, link, profile: str) -> None:
    """Raise the error that says why a recording gave no estimate."""
    from firmware_bridge.errors import LogFileError

    c = link.counters
    if not c.received and getattr(link, "bad_lines", 0):
        raise LogFileError(f"{log_file}: no line python-can can read as a CAN frame "
                           f"({link.bad_lines} bad lines; last: {link.last_bad_line})")
    if not c.received:
        raise LogFileError(f"{log_file}: no CAN frames in it; is it a CAN log written by "
                           "'iem record' or python-can?")
    other = next(p for p in PROFILES if p != profile)
    raise LogFileError(f"{log_file}: {c.received} frames but no complete joint-state "
                       f"cycle of the {profile} profile ({c.summary()}; {c.foreign} "
                       f"frames of other IDs); recorded with --profile {other}?")
