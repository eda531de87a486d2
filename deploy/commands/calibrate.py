"""``iem calibrate``: the arm's departure from its nominal model, from bare-arm traffic.

``iem calibrate REC... --out ARM`` reads recordings: CAN logs (``.blf .log .asc .trc``, decoded
by :class:`firmware_bridge.replay.ReplaySource` exactly as the live link decodes the bus),
rosbag2 bags of ``sensor_msgs/msg/JointState`` (directory, ``.db3``, ``.mcap``; ``--topic``,
default ``/franka/joint_states``) or joint-state CSVs (``t,q1..q7,dq1..dq7,tau1..tau7``), each
of the format ``--format`` names or else of the one detected
(:mod:`firmware_bridge.recordings`); ``iem calibrate --interface I --channel C --duration S
--out ARM`` reads a live link (:func:`firmware_bridge.links.open_link`) for ``S`` seconds
instead. The arm must carry no payload and should run the calibration motion
(:func:`sim.paths.calibration_path`, 30 s; ``iem calibrate --write-motion FILE.csv`` writes it
as a path CSV for the robot's own program); the traffic's rate is ``--rate HZ`` or else each
recording's detected from its time stamps (:mod:`iem.signals.rate`, 100 Hz to 1 kHz, one rate
for all, printed with the block size of the noise's equations: ``bare.csv at 200 Hz (detected),
block points of 2 frames: 100 per s``); ``--end-effector`` says what it carries as part of
itself (:mod:`sim.end_effector`; the prior is centred on that nominal arm). The numerics are
:mod:`sim.calibration` and :mod:`sim.calibration_noise` (the noise the fit leaves in IEM+phys's
equations, measured on traffic it did not see); this prints the per-joint residual RMS before
and after, the condition number of the excitation, that noise and any warning, and writes the
arm file (msgpack, versioned, CRC-checked; :mod:`sim.arm`), which ``iem train/run/replay/demo
--arm`` and the benchmarks use. ``--known-load REC... --known-payload TOML`` adds the torque
sensors' gain, read from recordings of the calibration motion with that known payload mounted
(:mod:`sim.calibration.gain`), which no bare recording shows.
"""

from __future__ import annotations

import time

import numpy as np

from deploy.options import (
    add_arm_model,
    add_end_effector,
    add_rate,
    add_recording_options,
    arm_description_of,
    recording_options,
    refuse_unused,
)
from firmware_bridge.recordings import DEFAULT_TOPIC
from iem.errors import InvalidInputError


def read_states(source, duration: float | None = None, silence_s: float = 1.0):
    """``(t, q, dq, tau)`` arrays of every joint state ``source`` gives (until its end, or
    ``duration`` s of controller time)."""
    from firmware_bridge.errors import EndOfStream

    rows = []
    t_end = None
    while True:
        try:
            s = source.read(silence_s)
        except EndOfStream:
            break
        except TimeoutError as exc:  # a live link that went silent
            raise InvalidInputError(f"the link gave no joint state for {silence_s:g} s after "
                                    f"{len(rows)} states; is the controller running? "
                                    f"({exc})") from exc
        rows.append((s.t, s.q, s.dq, s.tau_J))
        if duration is not None:
            t_end = s.t + duration if t_end is None else t_end
            if s.t >= t_end:
                break
    if not rows:
        return np.zeros(0), *(np.zeros((0, 7)) for _ in range(3))
    t = np.array([r[0] for r in rows])
    return t, *(np.array([r[i] for r in rows]) for i in (1, 2, 3))


def read_recordings(logs, format, topic, profile, joints) -> tuple[list, list]:
    """``(parts, names)``: the ``(t, q, dq, tau)`` of every joint state of each recording in
    ``logs`` (of ``format``, None: detected per file; a rosbag2 bag's ``topic`` and
    ``joints``; a CAN log's wire ``profile``), each split at its gaps later by the signal
    chain, and the recordings' names."""
    from firmware_bridge.recordings import open_recording

    parts, names = [], []
    for log_file in logs:
        replay = open_recording(log_file, format, topic=topic, profile=profile, joints=joints)
        try:
            data = read_states(replay)
        finally:
            replay.close()
        if data[0].size == 0:
            raise InvalidInputError(f"{log_file}: no complete joint-state cycle of the "
                                    f"{profile} profile in it")
        parts.append(data)
        names.append(str(log_file))
    return parts, names


def calibrate_sources(logs=(), *, interface=None, channel=None, duration=None,
                      profile: str = "fd", link=None, format: str | None = None,
                      topic: str = DEFAULT_TOPIC, end_effector=None,
                      rate_hz: float | None = None, log=print, description=None,
                      armature: bool = False):
    """The arm calibrated from the recordings ``logs`` (of ``format``, None: detected per
    file; ``topic``: a rosbag2 bag's JointState topic; ``profile``: a CAN log's wire profile)
    and/or a live link (see the module docstring): ``interface``/``channel`` opened here, or
    ``link`` already open (closed here); ``end_effector``: what the arm carries
    (:mod:`sim.end_effector`; None: the Franka Hand). The arm carries the noise it leaves,
    measured on traffic its fit did not see (:mod:`sim.calibration_noise`). ``rate_hz``:
    the traffic's joint states a second (None: each recording's detected from its time
    stamps and logged with ``log``; the recordings must share one). ``description``: the
    arm model (:mod:`sim.description`; None: the default), whose joint names a rosbag2 bag
    must carry.
    """
    from firmware_bridge.links import open_link
    from sim.calibration import CalibrationSettings
    from sim.calibration_noise import calibrate_with_noise
    from sim.description import described

    parts, names = read_recordings(logs, format, topic, profile,
                                   described(description).joint_names)
    if interface is not None or link is not None:
        if duration is None or not duration > 0:
            raise InvalidInputError("a live calibration needs --duration S (> 0 s): how long "
                                    "to record the calibration motion")
        if link is None:
            link = open_link(interface, channel or "", profile=profile)
        try:
            data = read_states(link, duration)
        finally:
            link.close()
        if data[0].size < 2:
            raise InvalidInputError(f"the link {interface}:{channel} gave {data[0].size} joint "
                                    f"state(s) before it ended; a calibration needs the "
                                    f"motion's traffic")
        parts.append(data)  # split at its gaps by the signal chain
        names.append(f"{interface}:{channel} for {duration:g} s")
    if not names:
        raise InvalidInputError("give at least one REC, or --interface/--channel/--duration")
    rate = traffic_rate(parts, names, rate_hz, log)
    return calibrate_with_noise(parts, CalibrationSettings(recorded_rate_hz=rate,
                                                           armature=armature),
                                source=", ".join(names), end_effector=end_effector,
                                description=description)


def traffic_rate(parts, names, rate_hz: float | None = None, log=print) -> float:
    """The joint states' rate of the traffic ``parts`` (``(t, q, dq, tau)`` each, named by
    ``names``): ``rate_hz`` if given, else each part's detected
    (:func:`iem.signals.rate.detect_rate`), which must be one rate; checked against
    :data:`iem.signals.rate.RATE_RANGE_HZ`. Each part's line goes to ``log``."""
    from iem.signals.rate import block_frames_for, check_rate, detect_rate, rate_line

    rates = [rate_hz if rate_hz is not None else detect_rate(p[0]) for p in parts]
    for rate, name in zip(rates, names, strict=True):
        check_rate(rate, name)
        log(rate_line(rate, block_frames_for(rate), rate_hz is None, name))
    if max(rates) > min(rates) * 1.02:
        listed = ", ".join(f"{n} at {r:g} Hz" for r, n in zip(rates, names, strict=True))
        raise InvalidInputError(f"the recordings have different rates ({listed}); calibrate "
                                "from recordings of one rate, the rate the arm will run at")
    return rates[0]


def print_report(arm, out, log=print) -> None:
    r = arm.report
    log(f"calibrated the arm from {r['source']}: {r['duration_s']:.1f} s in "
        f"{r['segments']} segment(s), {r['base_parameters']} base parameters, condition "
        f"number of the excitation {r['condition_number']:.0f}")
    log("residual torque RMS per joint (N·m), nominal model -> calibrated:")
    for j, (b, a) in enumerate(zip(r["rms_before"], r["rms_after"], strict=True)):
        log(f"  joint {j + 1}: {b:.4f} -> {a:.4f}")
    log("friction phi1 (N·m) " + " ".join(f"{v:.3f}" for v in arm.friction[:, 0]))
    log("offsets (N·m)       " + " ".join(f"{v:+.3f}" for v in arm.offset))
    if arm.armature.any():
        log("armature (kg·m²)    " + " ".join(f"{v:.3f}" for v in arm.armature))
    log(f"end effector: {arm.end_effector}")
    gain = r.get("gain")
    if gain is not None:
        log(f"torque sensors' gain, read with the known load {gain['payload']!r} "
            f"(joints {', '.join(map(str, gain['unmeasured'])) or 'none'} not turned enough "
            f"to read one):")
        log("  gain (-)            " + " ".join(f"{v:+.4f}" for v in arm.gain))
    if arm.noise is not None:
        n = arm.noise
        log(f"what the calibrated arm leaves in IEM+phys's equations ({n['cutoff_hz']:g} Hz "
            f"low-pass, {n['rate_hz']:g} Hz; {n['source']}):")
        log("  RMS per joint (N·m)         " + " ".join(f"{v:.3f}" for v in n["std"]))
        log("  correlation (equations/one) " + " ".join(f"{v:.1f}" for v in n["weight"]))
        log("  drifting offset (N·m)       " + " ".join(f"{v:.3f}" for v in n["offset_std"]))
        b = n["bias_std"]
        log(f"  reads as a payload of: mass {b[0]:.4f} kg, m·r {max(b[1:4]):.4f} kg·m, "
            f"inertia {max(b[4:]):.4f} kg·m² (RMS; a floor under the estimate's std)")
    if r["consistency_moved_bodies"]:
        log(f"bodies moved toward nominal to stay physically consistent: "
            f"{r['consistency_moved_bodies']}")
    for w in r["warnings"]:
        log(f"warning: {w}")
    log(f"wrote {out} (CRC32 {arm.crc32:#010x})")


def configure(parser) -> None:
    parser.add_argument("logs", nargs="*", metavar="REC",
                        help="recordings of the bare arm: CAN logs (.blf .log .asc .trc), "
                        "rosbag2 bags (directory, .db3, .mcap) or joint-state CSVs "
                        "(t,q1..q7,dq1..dq7,tau1..tau7)")
    parser.add_argument("--out", metavar="ARM", help="arm file to write")
    parser.add_argument("--write-motion", metavar="CSV",
                        help="write the calibration motion as a path CSV (t, q1..q7) and stop")
    add_recording_options(parser, "wire profile of CAN logs and of a live CAN link (default "
                                  "fd)")
    parser.add_argument("--interface", help="live link kind instead of (or besides) logs")
    parser.add_argument("--channel", help="live link channel")
    parser.add_argument("--duration", type=float, metavar="S",
                        help="seconds of live traffic to record")
    add_end_effector(parser)
    add_arm_model(parser)
    parser.add_argument("--armature", action="store_true",
                        help="fit each joint's armature (its drive's rotor inertia): for a "
                        "torque read from motor currents or a simulator's applied torque "
                        "(franky-sim's); not for Franka's link-side torque sensors")
    parser.add_argument("--known-load", nargs="+", metavar="REC",
                        help="recordings of the calibration motion with a known payload "
                        "mounted (--known-payload): the torque sensors' gain, which no bare "
                        "recording shows, is read from them")
    parser.add_argument("--known-payload", metavar="TOML",
                        help="the payload file of the load --known-load carries")
    add_rate(parser)


def known_load_gain(arm, logs, payload_file, *, format=None, topic=DEFAULT_TOPIC,
                    profile: str = "fd", rate_hz: float | None = None, log=print):
    """``arm`` with its torque sensors' gain read from the recordings ``logs`` of the known
    payload in ``payload_file`` (:func:`sim.calibration.gain.with_gain`), at the rate the arm
    was calibrated at; the fit's figures go to its report's ``gain``."""
    from sim.calibration import CalibrationSettings
    from sim.calibration.gain import with_gain
    from sim.payload import load_payload

    payload = load_payload(payload_file)
    parts, names = read_recordings(logs, format, topic, profile, arm.description.joint_names)
    rate = traffic_rate(parts, names, rate_hz, log)
    return with_gain(arm, parts, payload, CalibrationSettings(recorded_rate_hz=rate))


def run(args) -> int:
    from sim.arm import save_arm

    if args.write_motion:
        refuse_unused(args, [("REC", "logs"), "--out", "--interface", "--channel", "--duration",
                             "--format", "--topic", "--profile", "--end-effector", "--rate",
                             "--known-load", "--known-payload"],
                      "with --write-motion: it writes the motion for the arm model and stops")
        from sim.paths import calibration_path, save_path_csv
        from sim.robot import ArmModel

        motion = calibration_path(model=ArmModel(description=arm_description_of(args)))
        save_path_csv(motion, args.write_motion)
        print(f"wrote the calibration motion ({motion.duration:.0f} s) to {args.write_motion}")
        return 0
    if not args.out:
        raise InvalidInputError("--out ARM is required: the arm file to write")
    if args.interface is None:
        refuse_unused(args, ["--channel", "--duration"], "without --interface: they are the "
                      "live link's")
    if not args.logs and not args.known_load:
        refuse_unused(args, ["--format", "--topic"], "without a REC: they are the "
                      "recordings'")
    if bool(args.known_load) != bool(args.known_payload):
        raise InvalidInputError("--known-load REC... and --known-payload TOML go together: "
                                "the recordings of the calibration motion with a known "
                                "payload, and that payload's file")
    t0 = time.perf_counter()
    arm = calibrate_sources(args.logs, interface=args.interface, channel=args.channel,
                            duration=args.duration, **recording_options(args),
                            end_effector=args.end_effector, rate_hz=args.rate,
                            description=arm_description_of(args), armature=args.armature)
    if args.known_load:
        arm = known_load_gain(arm, args.known_load, args.known_payload,
                              **recording_options(args), rate_hz=args.rate)
    save_arm(arm, args.out)
    print_report(arm, args.out)
    print(f"({time.perf_counter() - t0:.1f} s)")
    return 0
