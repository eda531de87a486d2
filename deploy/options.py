"""Command-line options that several ``iem`` commands share, defined once."""

from __future__ import annotations

END_EFFECTOR_HELP = ("what the arm carries as part of itself: franka_hand, none, a "
                     "payload-style .toml of the tool, or Franka Desk's endeffector-config.json "
                     "(as set in Desk; default: the arm model's, the hand on panda and fr3); an "
                     "arm file or a model made for another is refused")


def add_arm_model(parser) -> None:
    """``--arm-model MODEL`` and ``--arm-flange LINK`` (:mod:`sim.description`)."""
    parser.add_argument("--arm-model", metavar="MODEL", default=None,
                        help="the arm's description: panda (default), fr3, or the path of a "
                        "URDF of another 7-joint torque-sensing arm; an arm file or "
                        "a model made for another is refused")
    parser.add_argument("--arm-flange", metavar="LINK", default=None,
                        help="the flange link of an --arm-model file that does not tell it "
                        "(a named arm model has its maker's)")


def seconds(text: str) -> float:
    """An ``argparse`` type: a finite number of seconds > 0 (``nan`` ran for ever, ``-5``
    stopped at once)."""
    import argparse
    import math

    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"{text!r}: valid is a number of seconds > 0")
    return value


def add_duration(parser) -> None:
    """``--duration S``: stop after this many seconds (a number > 0; default: until
    stopped)."""
    parser.add_argument("--duration", type=seconds, metavar="S",
                        help="stop after this many s (a number > 0; default: until stopped)")


def add_rated_mass(parser) -> None:
    """``--rated-mass-kg KG``, for the commands whose safety gate checks the rated payload."""
    parser.add_argument("--rated-mass-kg", metavar="KG", type=float, default=None,
                        help="the arm's rated payload, kg, which the gate checks (default: "
                        "the arm model's; an --arm-model file has none and needs it)")


def arm_description_of(args):
    """The arm model ``args`` name (``--arm-model``, ``--arm-flange``), read and checked.

    Raises:
        iem.errors.InvalidInputError: the description cannot be used, saying why; an
            ``--arm-flange`` with a named arm model, whose flange its maker defines (the
            frame the controller takes a load in)."""
    from iem.errors import InvalidInputError
    from sim.description import BUILTINS, DEFAULT_ARM_MODEL, arm_description

    model = getattr(args, "arm_model", None) or None
    flange = getattr(args, "arm_flange", None) or None
    name = model or DEFAULT_ARM_MODEL
    if flange is not None and name in BUILTINS:
        raise InvalidInputError(f"--arm-flange {flange} with the arm model {name!r}, which "
                                f"has its maker's flange, {BUILTINS[name].flange!r}: the "
                                "frame its controller takes a load in; --arm-flange is for an "
                                "--arm-model URDF file that does not tell its flange")
    return arm_description(model, flange)


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


def refuse_unused(args, options, why: str) -> None:
    """Refuse those of the command-line ``options`` that ``args`` holds a value for (not
    None, False, "" or []): the command does not use them ``why`` (e.g. ``"with --interface
    slcan-pty: ..."``). An option is its flag (``"--channel"``, read as ``args.channel``),
    or ``(name, attribute)`` for a positional (``("REC", "logs")``). An option that does
    nothing is refused rather than ignored: the operator meant something by it.

    Raises:
        iem.errors.InvalidInputError: naming the options given and why they do nothing."""
    from iem.errors import InvalidInputError

    pairs = [o if isinstance(o, tuple) else (o, o.lstrip("-").replace("-", "_"))
             for o in options]
    given = [name for name, attr in pairs
             if getattr(args, attr, None) not in (None, False, "", [])]
    if given:
        names = " and ".join(given) if len(given) < 3 else \
            ", ".join(given[:-1]) + f" and {given[-1]}"
        raise InvalidInputError(f"{names} {'has' if len(given) == 1 else 'have'} no effect "
                                f"{why}; leave {'it' if len(given) == 1 else 'them'} out")


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
    parser.add_argument("--topic", default=None, help="a rosbag2 bag's "
                        f"sensor_msgs/msg/JointState topic (default {DEFAULT_TOPIC})")
    parser.add_argument("--profile", default=None, choices=PROFILES, help=profile_help)


def recording_options(args) -> dict:
    """``format``, ``topic`` and ``profile`` as :func:`add_recording_options` read them
    (None where not given: so a command can tell an option it does not use), with their
    defaults: detected, :data:`firmware_bridge.recordings.DEFAULT_TOPIC`, ``"fd"``."""
    from firmware_bridge.recordings import DEFAULT_TOPIC

    return {"format": args.format, "topic": args.topic or DEFAULT_TOPIC,
            "profile": args.profile or "fd"}


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
