"""The plug-in's service in a process of its own, for :class:`deploy.service.PayloadPlugin`.

A franky or pylibfranka program calls its motion's callback from the robot's 1 kHz loop, and
that call needs the program's interpreter lock. Python has one lock per process: with the
service estimating in a thread of the program, the loop at real-time priority waits for a
thread of normal priority (measured with ``iem bench fci --fifo``: docs/decisions.md, "The
plug-in inside a program estimates in its own process"). So the service runs here, in a
child (``python -m deploy.service.plugin_process STATES_FD``), and the program's process
keeps the callback's queue and the thread that writes it to a pipe.

- States: on the pipe ``STATES_FD``, each the 35 doubles of
  :class:`firmware_bridge.franka_process.ProcessState` (time, ``q``, ``dq``, ``tau_J``,
  ``m_load``, ``F_x_Cload``, ``I_load`` column-major), fed to the ``program`` link
  (:class:`firmware_bridge.program_link.ProgramLink`) as the program's callback fed them.
- Commands, on standard input, each answered on standard output (pickled: parent and child
  are this code, over the child's own pipes): the configuration and model to start with
  (answered when the service runs, or with the exception that stopped it); ``take`` (the
  command the gate kept, once the states the program wrote are estimated); ``settle`` (the
  robot's answer to it: :meth:`ProgramLink.settle`); ``reading``; ``close`` (the run's
  summary; the model saved as the configuration says).
- The child ends when its standard input closes or its parent dies (``PR_SET_PDEATHSIG``).
  Anything it prints goes to standard error (the program's), never into the answers.

The robot stays in the program's process: :func:`firmware_bridge.program_link.write_load`
calls its ``set_load`` there, between motions.
"""

from __future__ import annotations

import json
import os
import pickle
import sys
import threading
import time

import numpy as np

from firmware_bridge.franka_process import (
    _HEADER,
    _STATE,
    ProcessState,
    _end_with_parent,
    _read_frame,
)

from .plugin import CLOSE, FAILED, READING, READY, REPLY, SETTLE, START, TAKE, TAKE_BODY

CATCH_UP_POLL_S = 0.002
CATCH_UP_S = 0.05
"""After the program's states are estimated, how long ``take`` gives the service for the last
block point and the gate's decision on it (its decision period), s."""


class PointRecords:
    """An ``on_cycle`` observer of ``service`` keeping every block point's time, smoothed
    mass and first moment and their standard deviations (``rows``), and the reason of the
    gate's latest decision then (``reasons``: the decision before that point's, as observers
    run before the gate's step; ``""`` before the first): what ``record_to`` writes."""

    def __init__(self, service) -> None:
        self.service, self.rows, self.reasons = service, [], []

    def __call__(self, record) -> None:
        s = np.asarray(record.smoothed, dtype=float)
        std = getattr(record.raw, "std", None)
        sd = [float("nan")] * 4 if std is None else [float(v) for v in np.asarray(std)[:4]]
        self.rows.append([float(record.state.t), *(float(v) for v in s[:4]), *sd])
        gate = self.service.gate
        self.reasons.append("" if gate is None else gate.verdict()["reason"])


def _child(argv: list[str]) -> int:
    if len(argv) != 1 or not argv[0].isdigit():
        sys.stderr.write("usage: python -m deploy.service.plugin_process STATES_FD\n")
        return 2
    _end_with_parent()
    # the answers get standard output's pipe to themselves: whatever else prints here goes to
    # standard error, never between two frames
    inp, out = sys.stdin.buffer, os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)
    sys.stdout = sys.stderr
    lock = threading.Lock()

    def emit(kind: bytes, value=None) -> None:
        body = pickle.dumps(value)
        with lock:
            out.write(_HEADER.pack(kind, len(body)) + body)
            out.flush()

    frame = _read_frame(inp)
    if frame is None or frame[0] != START:
        return 2
    config, model, record_to = pickle.loads(frame[1])
    try:
        from firmware_bridge.program_link import ProgramLink

        from .loop import Service
        from .plugin import Latest

        link = ProgramLink(None, None, silence_timeout=config.link.silence_timeout_s)
        service = Service(config, link=link, model=model)
        latest = Latest()
        service.on_cycle.append(latest)
        records = PointRecords(service) if record_to else None
        if records is not None:
            service.on_cycle.append(records)
        service.open()
    except Exception as exc:  # raised in the program as it was raised here
        emit(FAILED, exc)
        return 1
    summary: list = []
    runner = threading.Thread(target=lambda: summary.append(service.run()), name="service",
                              daemon=True)
    runner.start()
    fed = [0]

    def states() -> None:
        with os.fdopen(int(argv[0]), "rb") as stream:
            while True:
                got = _read_frame(stream)
                if got is None:
                    return
                link.feed(ProcessState(_STATE.unpack(got[1])))
                fed[0] += 1

    threading.Thread(target=states, name="states", daemon=True).start()
    emit(READY)
    while True:
        frame = _read_frame(inp)
        kind = CLOSE if frame is None else frame[0]
        if kind == TAKE:
            written, wait = TAKE_BODY.unpack(frame[1])
            deadline = time.monotonic() + wait
            while (fed[0] < written or link.backlog) and time.monotonic() < deadline:
                time.sleep(CATCH_UP_POLL_S)
            if time.monotonic() < deadline:
                time.sleep(min(CATCH_UP_S, deadline - time.monotonic()))  # its last decision
            emit(REPLY, link.take())
        elif kind == SETTLE:
            emit(REPLY, link.settle(*pickle.loads(frame[1])))
        elif kind == READING:
            emit(REPLY, latest.reading(link.load_report, service.gate.verdict()))
        elif kind == CLOSE:
            service.stop()
            runner.join()
            service.close()
            if records is not None:
                with open(record_to, "w", encoding="utf-8") as f:
                    json.dump({"rows": records.rows, "reasons": records.reasons}, f)
            if frame is not None:
                emit(REPLY, summary[0] if summary else None)
            return 0


if __name__ == "__main__":
    sys.exit(_child(sys.argv[1:]))
