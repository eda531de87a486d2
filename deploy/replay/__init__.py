"""The plug-in over recorded traffic, as fast as the machine goes (``iem replay``): one
recording through the same service ``iem run`` uses, writes off (:func:`replay`,
:mod:`.core`), a recording's replay as a picklable job with the command's options
(:mod:`.job`), many recordings in ``--jobs`` processes (:mod:`.many`), and what a replay
reports and prints (:mod:`.report`).
"""

from .core import CSV_HEADER, Estimates, replay, write_output
from .job import replay_inputs, replay_one, replay_options
from .many import recordings_of, run_many
from .report import add_replay_figures, print_summary, print_table

__all__ = ["CSV_HEADER", "Estimates", "add_replay_figures", "print_summary", "print_table",
           "recordings_of", "replay", "replay_inputs", "replay_one", "replay_options",
           "run_many", "write_output"]
