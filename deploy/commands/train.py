"""``iem train``: the initial model from the excitation path, written to a model file
(:func:`deploy.model.training.train_initial_model`)."""

from __future__ import annotations

from deploy.config import MODEL_KINDS
from deploy.model.training import NOISE_CHOICES, noise_for, train_initial_model
from deploy.options import (
    add_arm_model,
    add_block_frames,
    add_end_effector,
    add_rate,
    arm_description_of,
    refuse_unused,
)
from iem.ensemble.learners import LEARNERS
from iem.model_kinds import DEFAULT_MODEL
from iem.persistence import save_model
from iem.types import NOMINAL_RATE_HZ
from sim.family import DEPLOY_FAMILY, FAMILIES


def _seed(text: str) -> int:
    """A learners' seed: numpy's seeds are non-negative (argparse reports the error)."""
    import argparse

    try:
        value = int(text)
    except ValueError:
        value = -1
    if not 0 <= value < 2**63:
        raise argparse.ArgumentTypeError(f"{text!r}: valid is an integer from 0 to 2**63-1")
    return value

def configure(parser) -> None:
    parser.add_argument("--out", required=True, metavar="FILE", help="model file to write")
    parser.add_argument("--kind", default=DEFAULT_MODEL, choices=list(MODEL_KINDS),
                        help=f"model kind (default {DEFAULT_MODEL})")
    parser.add_argument("--family", default=DEPLOY_FAMILY, choices=sorted(FAMILIES),
                        help=f"training payload family (default {DEPLOY_FAMILY}: the paper's "
                             "container configurations and 77 random tools)")
    parser.add_argument("--excitation", "--path", dest="excitation", default="builtin",
                        metavar="CSV", help="excitation path CSV, as 'iem excite' writes it "
                        "and 'iem sim-controller --path' reads it (default: the built-in 20 s "
                        "path)")
    parser.add_argument("--seed", type=_seed, default=0,
                        help="seed of the learners (an integer from 0 to 2**63-1)")
    add_rate(parser, None, f"IEM+phys: joint states a second the link or the recordings "
             f"deliver (default {NOMINAL_RATE_HZ:g}: fd; classic 500; what 'iem replay' "
             "printed for a recording)")
    add_block_frames(parser)
    parser.add_argument("--arm", metavar="ARM", help="arm file from 'iem calibrate' (default: "
                        "the nominal arm)")
    add_end_effector(parser)
    add_arm_model(parser)
    parser.add_argument("--learner", choices=list(LEARNERS), default=None,
                        help="how the bags' learners are trained: 'sgd', the paper's "
                             "Algorithm 2, or 'expected', the same in expectation, exact "
                             "(microseconds a point and a refit); default: the kind's "
                             "(IEM sgd, IEM+phys expected)")
    parser.add_argument("--noise", choices=NOISE_CHOICES, default=None,
                        help="IEM+phys's equation error: 'arm', the arm file's measured "
                             "noise, or a conservative default for an uncalibrated arm; "
                             "'sensor', the sensor's white noise alone (a simulated arm whose "
                             "model is exact; on a real arm the model's data test then holds "
                             "the gate's writes); 'auto' (default): 'arm' with --arm, else "
                             "'sensor'")

def run(args) -> int:
    from iem.signals.rate import block_frames_for, rate_line

    rate, noise = args.rate or NOMINAL_RATE_HZ, noise_for(args.noise or "auto", args.arm)
    frames = args.block_frames or block_frames_for(rate)
    if args.kind == "IEM+phys":
        print(rate_line(rate, frames, detected=False, what="joint states"))
    else:
        refuse_unused(args, ["--rate", "--block-frames", "--noise"], f"with --kind "
                      f"{args.kind}: only IEM+phys works on block points at the link's rate "
                      "and weighs its equations' error")
    model = train_initial_model(args.kind, args.family, args.excitation, args.seed,
                                rate_hz=rate, arm_file=args.arm,
                                end_effector=args.end_effector, noise=noise,
                                block_frames=frames, description=arm_description_of(args),
                                **({} if args.learner is None else {"learner": args.learner}))
    save_model(model, args.out)
    print(f"wrote {args.out}")
    return 0
