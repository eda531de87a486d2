"""A watchdog for tests of inputs that once hung the reading: a block that runs longer than
its bound raises TimeoutError (a failure) instead of hanging the suite."""

from __future__ import annotations

import contextlib
import signal


@contextlib.contextmanager
def within(seconds: int):
    """Raise TimeoutError in the main thread if the block takes longer than ``seconds``
    (SIGALRM: Python code only; a call in C returns first)."""
    def expire(signum, frame):
        raise TimeoutError(f"still running after {seconds} s")

    old = signal.signal(signal.SIGALRM, expire)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)
