"""``iem identify``: commissioning identification of a payload from recorded traffic.

``iem identify --loaded REC --bare REC [--arm ARM] --out P.toml [--json S.json]
[--desk-json FILE]``

Each recording is a CAN log (``.blf``, ``.log``, ``.asc``, ``.trc``, as ``iem record`` writes
them), decoded by :class:`firmware_bridge.replay.ReplaySource` exactly as the live link decodes
the bus, as fast as the machine goes, or a rosbag2 bag of ``sensor_msgs/msg/JointState``
(directory, ``.db3``, ``.mcap``; ``--topic``, default ``/franka/joint_states``) or a
joint-state CSV (``t,q1..q7,dq1..dq7,tau1..tau7``), read by :mod:`firmware_bridge.recordings`;
``--format can|rosbag2|csv`` names the format of both, else each one's is detected; so is
each one's rate (:mod:`iem.signals.rate`: 100 Hz to 1 kHz; ``--rate HZ`` gives it), printed with
the rate of its equations (about 100 a second). The
numerics are :func:`sim.identify.identify` (see there for the method and the refusals). The
result is written as the project's payload TOML
(:func:`sim.payload.save_payload`: mass, CoM in the flange frame, inertia about the CoM) and,
with ``--json``, a summary holding ``payload {mass, com, inertia}`` and ``std {mass, com,
inertia}`` in the same units, plus the ten parameters, their standard deviations, which of
them the data determine, and the run's figures. With ``--arm``, ``--desk-json FILE`` also
writes Franka Desk's ``endeffector-config.json`` (:mod:`sim.desk_file`) of the declared end
effector and the payload as one body (a gripper with a camera added: Desk's end-effector
settings for what is mounted now), which ``--end-effector`` and ``[arm] end_effector`` take.

Errors (a missing or unreadable recording, recordings of different motions, too little
excitation, a load in the bare one) end with ``iem: error: ...`` and exit status 2; nothing is
written then.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path as FsPath

from deploy.options import (
    add_arm_model,
    add_end_effector,
    add_rate,
    add_recording_options,
    arm_description_of,
    recording_options,
    refuse_unused,
)
from firmware_bridge.protocol import PROFILES
from firmware_bridge.recordings import DEFAULT_TOPIC
from iem.errors import InvalidInputError


def read_log(path, profile: str = "fd", format: str | None = None,
             topic: str = DEFAULT_TOPIC, joints: tuple[str, ...] | None = None):
    """The joint states of a recording (``format`` None: detected; ``profile``: a CAN log's
    wire profile; ``topic``: a rosbag2 bag's JointState topic; ``joints``: the joint names
    it must carry, the arm model's) as a :class:`iem.signals.recording.Recording`."""
    from firmware_bridge.errors import LogFileError
    from firmware_bridge.recordings import read_recording, recording_format
    from firmware_bridge.replay import ReplaySource
    from iem.signals.recording import Recording

    fmt = recording_format(path, format)
    if fmt != "can":  # read whole and checked (at least 2 joint states)
        return read_recording(path, fmt, topic=topic, joints=joints)
    with ReplaySource(path, profile, pace="fast") as source:
        states = list(source)
        counters = source.counters
    if len(states) < 2:
        other = next(p for p in PROFILES if p != profile)
        raise LogFileError(f"{path}: {len(states)} complete joint-state cycle(s) of the "
                           f"{profile} profile ({counters.summary()}); a recording of the "
                           f"motion is needed (recorded with --profile {other}?)")
    return Recording.from_states(states)


def recording_rate_line(rec, rate_hz: float | None, what: str) -> str:
    """The line ``iem identify`` prints for a recording: its rate (``rate_hz``, or detected
    from its time stamps, :func:`iem.signals.rate.detect_rate`; 100 Hz to 1 kHz, else
    InvalidInputError) and its equations' rate."""
    from iem.signals.rate import check_rate, detect_rate
    from sim.identify import RATE_HZ

    rate = check_rate(detect_rate(rec.t) if rate_hz is None else rate_hz, what)
    every = max(1, round(rate / RATE_HZ))
    return (f"{what} at {rate:g} Hz ({'detected' if rate_hz is None else 'given'}), "
            f"equations every {every} sample{'s' if every > 1 else ''}: {rate / every:g} per s")


def configure(parser) -> None:
    parser.add_argument("--loaded", required=True, metavar="REC",
                        help="recording of the motion with the payload mounted: a CAN log "
                        "(.blf .log .asc .trc), a rosbag2 bag (directory, .db3, .mcap) or a "
                        "joint-state CSV (t,q1..q7,dq1..dq7,tau1..tau7)")
    parser.add_argument("--bare", metavar="REC",
                        help="recording of the same motion without the payload (any format)")
    parser.add_argument("--arm", metavar="ARM",
                        help="arm file from 'iem calibrate' instead of --bare (any motion)")
    add_end_effector(parser)
    add_arm_model(parser)
    parser.add_argument("--out", required=True, metavar="P.toml",
                        help="payload file to write (mass, CoM, inertia about the CoM)")
    parser.add_argument("--json", metavar="S.json", help="write the summary as JSON")
    parser.add_argument("--desk-json", metavar="FILE",
                        help="also write Franka Desk's endeffector-config.json of what the "
                        "flange carries now: the declared end effector (--end-effector, with "
                        "--arm) and the identified payload as one body; its transformation "
                        "(the TCP) is the declared end effector's (its Desk file's, the "
                        "Franka Hand's), else the identity: the dynamics do not tell it")
    add_recording_options(parser, "wire profile CAN logs were recorded with (default fd)")
    add_rate(parser, help="joint states a second of both recordings (default: each one's "
             "detected from its time stamps, the median step)")
    parser.add_argument("--name", help="payload name in the file (default: the file's stem)")


def print_result(result, summary: dict, log=print) -> None:
    p, s = summary["payload"], summary["std"]
    rep = result.report

    def vec(values, fmt):
        return "[" + ", ".join(format(v, fmt) for v in values) + "]"

    log(f"payload {p['name']!r}:")
    log(f"  mass    {p['mass']:.4f} ± {s['mass']:.4f} kg")
    log(f"  com     {vec(p['com'], '.5f')} ± {vec(s['com'], '.5f')} m")
    log(f"  inertia {vec(p['inertia'], '.6f')}")
    log(f"        ± {vec(s['inertia'], '.6f')} kg·m² about the CoM")
    prior = [k for k, v in summary["determined_by"].items() if v == "prior"]
    log("  determined by the data: " + ("all ten parameters" if not prior else
        "all but " + ", ".join(prior) + " (from the prior)"))
    before = max(rep["residual_rms_before"])
    after = max(rep["residual_rms_after"])
    ref = "loaded minus bare" if rep["reference"] == "bare" else "loaded minus arm model"
    log(f"  {rep['samples']} samples at {rep['rate_hz']:g} Hz; residual ({ref}) worst joint "
        f"RMS {before:.3f} -> {after:.4f} N·m")
    if rep["reference"] == "bare":
        log(f"  bare aligned by {rep['lag_s'] * 1e3:+.2f} ms over {rep['overlap_s']:.2f} s, "
            f"paths differ by at most {rep['path_diff_max_rad'] * 1e3:.2f} mrad")


def run(args) -> int:
    from sim.identify import identify
    from sim.payload import payload_to_toml

    if args.bare is None and args.arm is None:
        raise InvalidInputError("iem identify needs --bare LOG (a bare recording of the same "
                                "motion) or --arm ARM (an arm file from 'iem calibrate')")
    if args.bare is not None and args.arm is not None:
        raise InvalidInputError("iem identify takes one of --bare and --arm, not both")
    from deploy.model.training import load_arm_file
    from sim.robot import ArmModel

    if args.bare is not None:
        refuse_unused(args, ["--end-effector"], "with --bare: the bare recording carries the "
                      "arm and its end effector; it says what an --arm file is for")
        if args.desk_json:
            raise InvalidInputError("--desk-json needs --arm (and --end-effector): the Desk "
                                    "file holds the declared end effector with the payload, "
                                    "and a bare recording declares none")
    description = arm_description_of(args)
    joints = description.joint_names
    read = recording_options(args)
    start = time.perf_counter()
    loaded = read_log(args.loaded, read["profile"], read["format"], read["topic"], joints)
    bare = (read_log(args.bare, read["profile"], read["format"], read["topic"], joints)
            if args.bare is not None else None)
    decoded = time.perf_counter()
    for name, rec in (("loaded", loaded), ("bare", bare)):
        if rec is not None:
            print(recording_rate_line(rec, args.rate, f"{name} recording"))
    arm = None
    if args.arm is not None:  # the arm file must be for the declared end effector and model
        arm, _ = load_arm_file(args.arm, args.end_effector, description)
    result = identify(loaded, bare=bare, arm=arm, recorded_rate_hz=args.rate,
                      model=ArmModel(description=description))
    done = time.perf_counter()
    name = args.name or FsPath(args.out).stem or "identified"
    summary = result.summary(name)
    summary["files"] = {"loaded": str(args.loaded), "bare": args.bare, "arm": args.arm,
                        "profile": read["profile"]}
    summary["time_s"] = {"decode": decoded - start, "identify": done - decoded}
    payload = result.payload(name).check()
    _write(args.out, payload_to_toml(payload, phi_std=result.std))
    if args.json:
        _write(args.json, json.dumps(summary, indent=2) + "\n")
    if args.desk_json:
        _write(args.desk_json, desk_text(payload, args.end_effector, description, name))
    print_result(result, summary)
    print(f"  wrote {args.out}" + "".join(f" and {f}" for f in (args.json, args.desk_json) if f)
          + f" ({decoded - start:.2f} s decoding, {done - decoded:.2f} s identifying)")
    return 0


def desk_text(payload, end_effector, description, name: str) -> str:
    """Franka Desk's ``endeffector-config.json`` (:mod:`sim.desk_file`) of the end effector
    ``end_effector`` (a spec; None: the arm model's) with ``payload`` on it, as one body."""
    from sim.desk_file import base_of, desk_document
    from sim.end_effector import end_effector_of

    ee = end_effector_of(end_effector, description)
    body = ee.with_payload(payload, name=name)
    ident = "".join(c if c.isalnum() or c in "-_." else "-" for c in name).lstrip("-") or "tool"
    if ident.startswith("ee-"):
        ident = ident[3:] or "tool"
    doc = desk_document(body, base=base_of(ee.spec), id=ident, name=f"{ee.label} + {name}")
    return json.dumps(doc, indent=2) + "\n"


def _write(path, text: str) -> None:
    try:
        FsPath(path).write_text(text, encoding="utf-8")
    except OSError as exc:
        raise InvalidInputError(f"{path}: cannot write: {exc.strerror or exc}") from exc


if __name__ == "__main__":  # pragma: no cover
    from deploy.cli import main

    sys.exit(main(["identify", *sys.argv[1:]]))
