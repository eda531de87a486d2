"""``iem replay REC...``: the plug-in over one recording (:mod:`deploy.replay.core` says how),
or over many, each in a job of its own, ``--jobs`` at once (:mod:`deploy.replay.many`); the
exit status is 2 when a recording of many failed."""

from __future__ import annotations

import json
import sys

from deploy.cli import EX_ERROR
from deploy.options import (
    add_arm_model,
    add_block_frames,
    add_end_effector,
    add_rate,
    add_rated_mass,
    add_recording_options,
    refuse_unused,
)
from iem.model_kinds import DEFAULT_MODEL


def jobs(text: str) -> int:
    """A ``--jobs`` value: a whole number of at least 1 (argparse reports the error)."""
    import argparse

    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: valid is a whole number of processes, "
                                         "1 or more")
    return value


def add_jobs(parser) -> None:
    """``--jobs N``: how many recordings replay at once, each in its own process."""
    parser.add_argument("--jobs", type=jobs, default=None, metavar="N", help="with several "
                        "recordings, replay N at once, each in its own process (default 1: "
                        "one after another)")


def configure(parser) -> None:
    parser.add_argument("files", nargs="+", metavar="REC", help="the recording: a CAN log "
                        "(.blf, .log, .asc, .trc), a rosbag2 bag (directory, .db3, .mcap) or "
                        "a joint-state CSV (t,q1..q7,dq1..dq7,tau1..tau7); or a folder of "
                        "them, a quoted glob or several, each replayed on its own (--jobs)")
    add_recording_options(parser, "wire profile a CAN log was recorded with (default fd)")
    parser.add_argument("--model", metavar="FILE", help="model file to start from (read "
                        f"only; default: a fresh {DEFAULT_MODEL} trained on the built-in "
                        "excitation path, seed 0)")
    parser.add_argument("--truth", metavar="PAYLOAD", help="payload TOML: report the MAE of "
                        "the smoothed estimates against it")
    parser.add_argument("--out", metavar="CSV", help="write every estimate (raw and smoothed); "
                        "with several recordings a folder, one CSV each")
    parser.add_argument("--json", metavar="FILE", help="write the summary as JSON (with "
                        "several recordings, every one's)")
    parser.add_argument("--arm", metavar="ARM", help="arm file of the recorded arm (from "
                        "'iem calibrate'; the model must have been trained for it)")
    add_end_effector(parser)
    add_arm_model(parser)
    add_rated_mass(parser)
    add_rate(parser, help="joint states a second of the recording (default: detected from "
             "its time stamps, the median step)")
    add_block_frames(parser)
    parser.add_argument("--save-model", metavar="FILE",
                        help="save the model learnt during the replay here (with several "
                        "recordings a folder, one model each)")
    parser.add_argument("--no-status", action="store_true", help="no live status line")
    add_jobs(parser)


def run(args) -> int:
    from deploy.replay.core import replay, write_output
    from deploy.replay.job import replay_inputs, replay_options
    from deploy.replay.many import recordings_of, run_many
    from deploy.replay.report import print_summary
    from deploy.service.logs import setup_logging

    setup_logging("warning", "text")
    files = recordings_of(args.files, args.format)
    if files is not None:  # a folder, a glob or several: each on its own, then a table
        entries = run_many(args, files)
        failed = [e["file"] for e in entries if e["error"] is not None]
        if failed:
            print(f"iem: error: {len(failed)} of {len(entries)} recordings failed: "
                  f"{', '.join(failed)}", file=sys.stderr)
            return EX_ERROR
        return 0
    refuse_unused(args, ["--jobs"], "with one recording: it is how many of several replay at "
                  "once")
    truth, model = replay_inputs(args)

    def log(msg: str) -> None:
        print(msg, file=sys.stderr, flush=True)

    summary, estimates = replay(args.files[0], model=model, truth=truth,
                                save_model_to=args.save_model,
                                status=not args.no_status and sys.stderr.isatty(), log=log,
                                **replay_options(args))
    if args.out:
        estimates.write_csv(args.out)
    if args.json:
        write_output(args.json, json.dumps(summary, indent=2, default=float) + "\n")
    print_summary(summary)
    return 0
