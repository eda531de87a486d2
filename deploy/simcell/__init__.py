"""The simulated cell: the simulated controller (:class:`SimController`, :mod:`.controller`:
the MuJoCo plant at 1 kHz behind a bus or link), the path it plays (:mod:`.path_player`),
the payloads it mounts on a schedule (:mod:`.payload_schedule`), its ROS 2 side in a process
of its own (:mod:`.ros2_controller`), a cell in one process with the service beside it
on the virtual bus (:mod:`.inprocess`; its configuration: :func:`deploy.config.cell_config`),
and a robot this project did not write: franky-sim's FR3 served over the libfranka protocol,
with a payload in its physics (:class:`FciSim`, :mod:`.fci_sim`).
"""

from .controller import SimController
from .fci_sim import FciSim, FciSimError
from .inprocess import simulated_cell, virtual_channel, virtual_link
from .path_player import PathPlayer
from .payload_schedule import PayloadSchedule, parse_schedule

__all__ = ["FciSim", "FciSimError", "PathPlayer", "PayloadSchedule", "SimController",
           "parse_schedule", "simulated_cell", "virtual_channel", "virtual_link"]
