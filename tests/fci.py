"""What the tests against franky-sim's FR3 share (:class:`deploy.simcell.FciSim`).

libfranka's UDP receive times out (``libfranka: UDP receive: Timeout``) when no robot state
arrived for a second. In these tests that happened about one run in eight, and the cause
was one process holding Python's interpreter lock: pylibfranka's ``read_once`` waits for the
next state without releasing it, so a reader thread in the test's process kept the thread
sending a long motion to the scene from writing the rest of it, while the scene's loop
waited for that rest and sent no state. The ``franka`` link now reads in a process of its
own and the scene receives in a thread of its own; three runs of these tests in a row
passed without a re-run. :data:`STALL_RERUN` stays as a guard against the scene's 1 kHz
loop stopping for a second on a machine loaded beyond that: it re-runs a test that failed on
exactly those words, and on nothing else, at most twice.
"""

from __future__ import annotations

import pytest

STALL = "UDP receive: Timeout"
"""libfranka's words when no robot state arrived for its timeout (1 s)."""
STALL_RERUN = pytest.mark.flaky(reruns=2, only_rerun=[STALL])
"""The mark of a test against franky-sim: re-run when franky-sim's stream stalled."""
