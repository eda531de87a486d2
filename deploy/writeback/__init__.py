"""Everything between an estimate and the controller's ``setLoad``: the safety gate
(:class:`SafetyGate`), the checks it makes of one estimate (:mod:`.checks`), its settings
(:class:`GateConfig`), the load in force as the controller confirms it (:mod:`.load_state`),
the rule that a write must make the controller's model better (:mod:`.write_rule`), the time
window of stability (:mod:`.time_window`), the writer that sends what the gate lets through
(:class:`LoadWriter`) and the wire's range check of a load (:func:`wire_check_of`); whether
an estimate's mass is told from zero (:func:`excludes_zero`), as the gate and the status line
judge it.

It imports neither ``sim`` nor anything of ``deploy`` outside this folder: what it decides
rests on the estimate, the settings and the controller's answers alone.
"""

from .checks import WireCheck, check_estimate, excludes_zero
from .gate import REASONS, Decision, SafetyGate
from .load_state import LoadInForce, load_record, same_load
from .settings import RANGES, GateConfig
from .time_window import TimeWindow
from .wire import wire_check_of
from .write_rule import RecentMotion
from .writer import LoadWriter

__all__ = ["RANGES", "REASONS", "Decision", "GateConfig", "LoadInForce", "LoadWriter",
           "RecentMotion", "SafetyGate", "TimeWindow", "WireCheck", "check_estimate",
           "excludes_zero", "load_record", "same_load", "wire_check_of"]
