"""What a robot-cell PC runs: the plug-in service, its command line and its configuration.

The rooms, each a package that names its public interface in its ``__init__``, from the
bottom floor up (a room imports only the rooms below it; ``tests/test_layers.py`` holds the
order):

- :mod:`deploy.options`: the command-line options that commands, benches and the jobs of a
  replay share (``--arm-model``, ``--end-effector``, ``--rate``, ...);
- :mod:`deploy.writeback`: everything between an estimate and the controller's ``setLoad``:
  the safety gate, its checks and settings, the load in force, the write rule, the writer
  and the wire's range check. It imports neither ``sim`` nor anything of ``deploy`` outside
  itself;
- :mod:`deploy.config`: ``cell.toml``: its sections, how a file is read and checked, and the
  ``[arm]`` section's checks across sections;
- :mod:`deploy.model`: the model a cell runs: training the initial model on the excitation
  path, and loading and checking the configured one against the link and the arm;
- :mod:`deploy.service`: the running plug-in (``iem run``): the loop, the link reader,
  pacing, latency, the arm watch, checkpoints, its report, status line, logs, systemd
  notification and what it asks of the host;
- :mod:`deploy.replay`: the plug-in over recorded traffic: one recording, a picklable job,
  many at once, and the report;
- :mod:`deploy.simcell`: the simulated cell: the simulated controller and what it plays and
  mounts, its ROS 2 side, the in-process cell and the configuration a cell against it has;
- :mod:`deploy.cli`: the ``iem`` command: the table of commands (loaded by name when one
  runs) and the exit statuses;
- :mod:`deploy.commands` and :mod:`deploy.bench`: a module per ``iem`` command and per
  ``iem bench`` benchmark, each ``configure(parser)`` and ``run(args)``.

Beside them lie the data files a cell installs: ``cell.toml`` (every key, documented),
``iem.service`` (the systemd unit) and ``setup-vcan.sh``.
"""
