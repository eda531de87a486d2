"""The running plug-in (``iem run``): the service (:class:`Service`, :mod:`.loop`: joint
states in, identified payload out, one loop) and its parts: the link reader that forms block
points (:mod:`.reader`), learning paced to keep up (:mod:`.pacing`), latency windows
(:mod:`.latency`), the wrong-arm watch (:mod:`.arm_watch`), checkpoints of the model
(:mod:`.checkpointer`), what the link must declare for its kind (:mod:`.capabilities`), the
run's report (:mod:`.report`), the terminal status line (:mod:`.status`), logs
(:mod:`.logs`), systemd's notification (:mod:`.sdnotify`) and what it asks of the host
(:mod:`.host`).
"""

from .capabilities import check_sink, wire_check_for
from .host import hold_cpu_latency
from .logs import setup_logging
from .loop import CycleRecord, Service
from .reader import BatchReader, LinkReader
from .sdnotify import Notifier
from .status import StatusLine

__all__ = ["BatchReader", "CycleRecord", "LinkReader", "Notifier", "Service", "StatusLine",
           "check_sink", "hold_cpu_latency", "setup_logging", "wire_check_for"]
