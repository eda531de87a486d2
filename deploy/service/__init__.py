"""The running plug-in (``iem run``): the service (:class:`Service`, :mod:`.loop`: joint
states in, identified payload out, one loop, with a lifecycle of configure, activate,
deactivate and shut down) and its parts: the link reader that forms block points
(:mod:`.reader`), learning paced to keep up (:mod:`.pacing`), what one run counts
(:class:`RunTally`, :mod:`.tally`), the failures of a service kept in order, the first first
(:class:`Failures`, :mod:`.failures`), latency windows (:mod:`.latency`), the wrong-arm watch
(:mod:`.arm_watch`), checkpoints of the model (:mod:`.checkpointer`), what the link must
declare for its kind (:mod:`.capabilities`), the run's report and its summary in words
(:mod:`.report`), the terminal status line (:mod:`.status`), logs and the fatal line
(:mod:`.logs`), systemd's notification (:mod:`.sdnotify`) and what it asks of the host
(:mod:`.host`); and the same service inside a user's own franky or pylibfranka program
(:class:`PayloadPlugin`, :mod:`.plugin`).
"""

from .capabilities import check_sink, wire_check_for
from .failures import Failures
from .host import hold_cpu_latency
from .logs import log_failure, setup_logging
from .loop import CycleRecord, Service
from .plugin import PayloadPlugin, Reading
from .reader import BatchReader, LinkReader
from .report import summary_lines
from .sdnotify import Notifier
from .status import StatusLine
from .tally import RunTally

__all__ = ["BatchReader", "CycleRecord", "Failures", "LinkReader", "Notifier", "PayloadPlugin",
           "Reading", "RunTally", "Service", "StatusLine", "check_sink", "hold_cpu_latency",
           "log_failure", "setup_logging", "summary_lines", "wire_check_for"]
