"""``iem excite``: a short motion that determines a payload, as a path CSV.

``iem excite --seconds N --out path.csv [--start Q1,...,Q7] [--restarts K] [--arm-model ARM]
[--json F]``

The motion is :func:`sim.excite.excite_path`'s: a finite Fourier series per joint from and
back to the start pose at rest (default: the arm model's home), within the arm model's joint
range and 75 % of its velocity and acceleration limits, whose shape maximises the payload's
information (D-optimal design on the payload regressor). The CSV
(:func:`sim.path_csv.save_path_csv`: ``t,q1..q7`` at 1 kHz) is what ``iem sim-controller
--path``, ``iem train --excitation`` and a franky program (a joint waypoint per row) read.
It prints the motion's duration, its condition number (the scaled payload regressor's, below
which every payload parameter is seen) and its peaks against the limits; ``--json`` writes
them. A start pose outside the limits, a duration out of range or an unwritable file ends
with ``iem: error: ...`` and exit status 2, nothing written.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path as FsPath

from deploy.options import add_arm_model, arm_description_of
from iem.errors import InvalidInputError
from sim.excite import RESTARTS


def _start(text: str | None):
    """The start pose of ``--start`` (None: the arm model's home)."""
    if text is None:
        return None
    try:
        return [float(v) for v in text.split(",")]
    except ValueError as exc:
        raise InvalidInputError(f"--start {text!r}: valid is 7 joint angles in rad, comma-"
                                f"separated, e.g. 0,-0.3,0,-2.2,0,2,0.8") from exc


def configure(parser) -> None:
    parser.add_argument("--seconds", type=float, required=True,
                        help="the motion's duration, s (2 to 120)")
    parser.add_argument("--out", required=True, metavar="CSV", help="path CSV to write")
    parser.add_argument("--start", metavar="Q1,...,Q7",
                        help="start (and end) pose, rad (default: the arm model's home)")
    parser.add_argument("--seed", type=int, default=0,
                        help="seed of the design's random starting shapes")
    parser.add_argument("--restarts", type=int, default=RESTARTS,
                        help=f"random starting shapes the design tries (default {RESTARTS}; "
                        "fewer: a quicker, less optimised motion)")
    parser.add_argument("--json", metavar="FILE", help="write the design's figures as JSON")
    add_arm_model(parser)


def run(args) -> int:
    import numpy as np

    from sim.excite import excite_path
    from sim.paths import save_path_csv
    from sim.robot import ArmModel

    model = ArmModel(description=arm_description_of(args))
    print(f"designing a {args.seconds:g} s motion on {model.description.name} ...",
          file=sys.stderr)
    path, design = excite_path(args.seconds, _start(args.start), model=model, seed=args.seed,
                               restarts=args.restarts)
    out = FsPath(args.out)
    try:
        save_path_csv(path, out)
    except OSError as exc:
        raise InvalidInputError(f"{out}: cannot write the path CSV ({exc})") from exc
    share = {k: np.array(getattr(design, f"{k}_peak")) / np.array(limit)
             for k, limit in (("q", design.q_room), ("dq", design.dq_max),
                              ("ddq", design.ddq_max))}
    print(f"wrote {out}: {path.duration:g} s, condition number {design.condition:.0f} "
          f"(the payload regressor, scaled); peaks: q {share['q'].max():.2f} of the room to "
          f"the joint limits, dq {share['dq'].max():.2f} and ddq {share['ddq'].max():.2f} of "
          f"the limits")
    if args.json:
        figures = {"file": str(out), "seconds": path.duration, "arm_model": model.description.name,
                   **{k: (list(v) if isinstance(v, tuple) else v)
                      for k, v in design.__dict__.items()}}
        FsPath(args.json).write_text(json.dumps(figures, indent=2) + "\n", encoding="utf-8")
    return 0
