"""The controller's end of a link: the port a controller publishes joint states through.

:func:`open_port` opens the controller's side of a link kind the controller serves (a
:class:`~firmware_bridge.can_link.CanControllerPort` on a python-can bus or an emulated slcan
adapter, a :class:`~firmware_bridge.serial_link.SerialControllerPort` on a serial device or
a pty), with the faults of :func:`fault_spec` injected on what it sends. The simulated
controller (:mod:`deploy.simcell.controller`) and the link check suite
(:class:`firmware_bridge.link_harness.ControllerHarness`) stand behind it.
"""

from __future__ import annotations


def fault_spec(args):
    """The :class:`~firmware_bridge.faults.FaultSpec` of the command-line fault options
    (``--drop``, ``--corrupt``, ``--duplicate``, ``--delay``, ``--delay-cycles``,
    ``--silence START:LENGTH``, ``--fault-seed``)."""
    from .errors import BridgeConfigError
    from .faults import FaultSpec

    silence_at, silence_for = None, 0.0
    if args.silence:
        try:
            a, b = args.silence.split(":")
            silence_at, silence_for = float(a), float(b)
        except ValueError:
            raise BridgeConfigError(f"--silence {args.silence!r}: expected START:LENGTH in s, "
                                    "e.g. 2.0:0.5") from None
    given = {"delay_cycles": args.delay_cycles, "seed": args.fault_seed}  # None: the default
    return FaultSpec(drop=args.drop, corrupt=args.corrupt, duplicate=args.duplicate,
                     delay=args.delay, silence_at=silence_at, silence_for=silence_for,
                     **{k: v for k, v in given.items() if v is not None})


def open_port(interface: str, channel: str, profile: str, faults=None,
              record_faults: bool = False):
    """``(port, announce)``: the controller port, and the pty path to print (or None).
    ``interface`` is a link kind the controller serves, or ``<kind>-pty`` (see
    :func:`firmware_bridge.links.controller_interfaces`). ``record_faults`` keeps a log of
    every fault drawn (for tests)."""
    from .errors import BridgeConfigError
    from .links import LINKS, controller_interfaces

    valid = controller_interfaces()
    if interface not in valid:
        raise BridgeConfigError(f"unknown interface {interface!r}; valid are {', '.join(valid)}")
    kind, pty = interface.removesuffix("-pty"), interface.endswith("-pty")
    spec = LINKS[kind]
    if spec.bus is not None:
        from .can_link import CanControllerPort, open_bus

        if pty:
            from .slcan_adapter import SlcanPtyAdapter

            adapter = SlcanPtyAdapter()
            return CanControllerPort(adapter, profile, faults,
                                     record_faults=record_faults), adapter.slave_path
        return CanControllerPort(open_bus(kind, channel, profile), profile, faults,
                                 record_faults=record_faults), None
    from .serial_link import SerialControllerPort, open_serial

    if not pty:
        return SerialControllerPort(open_serial(channel), faults=faults,
                                    record_faults=record_faults), None
    from .pty_pair import PtyPair

    pty_port = PtyPair()
    return SerialControllerPort(pty_port, faults=faults,
                                record_faults=record_faults), pty_port.slave_path
