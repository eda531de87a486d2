"""The running plug-in (``iem run``): the service (:class:`Service`, :mod:`.loop`: joint
states in, identified payload out, one loop) and its parts: the link reader that forms block
points (:mod:`.reader`), learning paced to keep up (:mod:`.pacing`), latency windows
(:mod:`.latency`), the wrong-arm watch (:mod:`.arm_watch`), checkpoints of the model
(:mod:`.checkpointer`), what the link must declare for its kind (:mod:`.capabilities`), the
run's report (:mod:`.report`), the terminal status line (:mod:`.status`), logs
(:mod:`.logs`), systemd's notification (:mod:`.sdnotify`) and what it asks of the host
(:mod:`.host`); and the same service inside a user's own franky or pylibfranka program
(:class:`PayloadPlugin`, :mod:`.plugin`).
"""

from .capabilities import check_sink, wire_check_for
from .host import hold_cpu_latency
from .logs import setup_logging
from .loop import CycleRecord, Service
from .plugin import PayloadPlugin, Reading
from .reader import BatchReader, LinkReader
from .sdnotify import Notifier
from .status import StatusLine

__all__ = ["BatchReader", "CycleRecord", "LinkReader", "Notifier", "PayloadPlugin", "Reading",
           "Service", "StatusLine",
           "check_sink", "hold_cpu_latency", "setup_logging", "wire_check_for"]
