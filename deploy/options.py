"""Command-line options that several ``iem`` commands share, defined once."""

from __future__ import annotations

END_EFFECTOR_HELP = ("what the arm carries as part of itself: franka_hand, none, or a "
                     "payload-style .toml of the tool, as set in Franka Desk (default: the arm "
                     "model's, the hand on panda and fr3); an arm file or a model made for "
                     "another is refused")


def add_arm_model(parser) -> None:
    """``--arm-model MODEL`` and ``--arm-flange LINK`` (:mod:`sim.description`)."""
    parser.add_argument("--arm-model", metavar="MODEL", default=None,
                        help="the arm's description: panda (default), fr3, or the path of a "
                        "URDF of another 7-joint torque-sensing arm; an arm file or "
                        "a model made for another is refused")
    parser.add_argument("--arm-flange", metavar="LINK", default=None,
                        help="the flange link of an --arm-model file that does not tell it")
    parser.add_argument("--rated-mass-kg", metavar="KG", type=float, default=None,
                        help="the arm's rated payload, kg, which the gate checks (default: "
                        "the arm model's; an --arm-model file has none and needs it)")


def arm_description_of(args):
    """The arm model ``args`` name (``--arm-model``, ``--arm-flange``), read and checked.

    Raises:
        iem.errors.InvalidInputError: the description cannot be used, saying why."""
    from sim.description import arm_description

    return arm_description(getattr(args, "arm_model", None) or None,
                           getattr(args, "arm_flange", None) or None)


def arm_model_options(description) -> list[str]:
    """The options that name the arm model ``description`` (an
    :class:`~sim.description.ArmDescription`; None: the default) on another command's line
    (``iem sim-controller``'s): ``--arm-model``, and ``--arm-flange`` for a file."""
    if description is None:
        return []
    out = ["--arm-model", description.source_spec]
    if description.source_spec == description.source:  # a file, not a named arm model
        out += ["--arm-flange", description.flange]
    return out


def add_end_effector(parser, help: str = END_EFFECTOR_HELP) -> None:
    """``--end-effector EE`` (:mod:`sim.end_effector`; default None: the Franka Hand)."""
    parser.add_argument("--end-effector", metavar="EE", default=None, help=help)


def add_recording_options(parser, profile_help: str) -> None:
    """``--format``, ``--topic`` and ``--profile`` of the commands that read recordings
    (:mod:`firmware_bridge.recordings`)."""
    from firmware_bridge.protocol import PROFILES
    from firmware_bridge.recordings import DEFAULT_TOPIC, FORMATS

    parser.add_argument("--format", choices=FORMATS, help="the recordings' format (default: "
                        "detected from each file)")
    parser.add_argument("--topic", default=DEFAULT_TOPIC, help="a rosbag2 bag's "
                        f"sensor_msgs/msg/JointState topic (default {DEFAULT_TOPIC})")
    parser.add_argument("--profile", default="fd", choices=PROFILES, help=profile_help)


def block_frames(text: str) -> int:
    """A ``--block-frames`` value: an integer from 1 to 100 (argparse reports the error)."""
    import argparse

    try:
        value = int(text)
    except ValueError:
        value = 0
    if not 1 <= value <= 100:
        raise argparse.ArgumentTypeError(f"{text!r}: valid is an integer from 1 to 100")
    return value


def add_block_frames(parser) -> None:
    """``--block-frames N``: frames per block point (:mod:`iem.signals.blocks`; ``[estimate]
    block_frames``); default None: :func:`iem.signals.rate.block_frames_for` the rate."""
    parser.add_argument("--block-frames", type=block_frames, default=None,
                        metavar="N", help="the estimator works on the means of N "
                        "consecutive joint states (default: round(rate / 100), about 100 "
                        "points per second: 10 at 1 kHz, 2 at 200 Hz); the model must be made "
                        "for the same")


def rate(text: str) -> float:
    """A ``--rate`` value: joint states a second in :data:`iem.signals.rate.RATE_RANGE_HZ`
    (argparse reports the error)."""
    import argparse

    from iem.errors import InvalidInputError
    from iem.signals.rate import check_rate

    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: valid is a number of Hz") from None
    try:
        return check_rate(value)
    except InvalidInputError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_rate(parser, default=None, help: str = "joint states a second of the recordings "
             "(default: detected from their time stamps, the median step)") -> None:
    """``--rate HZ``: the joint states' rate (:mod:`iem.signals.rate`)."""
    parser.add_argument("--rate", type=rate, default=default, metavar="HZ", help=help)
