"""A simulated cell in one process: the simulated controller in a thread on python-can's
virtual bus, and the plug-in service against it (the demo, ``iem bench e2e`` and the
end-to-end tests).

The virtual bus does not cross processes, so both share the interpreter; the thread switch
interval is lowered to 0.5 ms while the cell runs, so the controller's 1 kHz loop is not held
up for the default 5 ms by the plug-in's longer steps, and restored afterwards.
"""

from __future__ import annotations

import contextlib
import os
import sys
from itertools import count

_channels = count()


def virtual_channel(tag: str) -> str:
    """A virtual-bus channel name no other cell in this process uses."""
    return f"iem-{tag}-{os.getpid()}-{next(_channels)}"


def virtual_link(tag: str) -> dict:
    """The ``[link]`` of a cell in this process: the virtual bus on a channel of its own
    (:func:`virtual_channel`), the fd profile."""
    return {"kind": "virtual", "channel": virtual_channel(tag), "profile": "fd"}


@contextlib.contextmanager
def simulated_cell(config, *, path=None, payload=None, once: bool = False, seed: int = 0,
                   faults=None, model=None, status=None, **options):
    """Open ``config``'s service (its link must be ``virtual``) and a controller on the same
    channel; yield ``(controller, service)`` with the service open and the controller not yet
    started (so the service's start-up, e.g. training, does not count against the run).
    ``options``: more of :class:`deploy.simcell.controller.SimController`'s options
    (``drop_commands``, ``payload_schedule``, ``refuse_while_moving``, ``gap``).

    On the way out: the controller is stopped (its error, if any, re-raised), the service
    closed (final checkpoint), the bus closed and the switch interval restored.
    """
    from deploy.service.loop import Service
    from deploy.service.status import StatusLine
    from firmware_bridge.controller_port import open_port
    from iem.extras import require

    from .controller import SimController

    link = config.link
    if link.kind != "virtual":
        raise ValueError(f"a simulated cell runs on the virtual bus, not {link.kind!r}")
    require("mujoco", "a simulated cell (its controller's plant)")  # before the bus opens
    previous = sys.getswitchinterval()
    sys.setswitchinterval(0.0005)
    port, _ = open_port("virtual", link.channel, link.profile, faults,
                        record_faults=faults is not None)
    controller = SimController(port, path=path, payload=payload, once=once, seed=seed,
                              **options)
    service = Service(config, model=model,
                      status=StatusLine(False) if status is None else status)
    try:
        service.open()
        yield controller, service
    finally:
        controller.stop()
        try:
            service.close()
        finally:
            port.close()
            sys.setswitchinterval(previous)
    if controller.error is not None:
        raise controller.error
