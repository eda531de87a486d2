"""The hardware-abstraction layer: wire protocol, CAN and serial links, record and replay.

The plug-in's only way to the robot. Modules, one concept each:

- ``protocol.dbc``: every frame, its signals, scaling, rates and E2E data IDs (cantools).
- :mod:`.protocol`: the DBC loaded once; codecs per profile (``fd``, ``classic``), built
  from :mod:`.frame_codec`, :mod:`.state_codec` and :mod:`.control_codecs`.
- :mod:`.messages`: payload command, acknowledgement and heartbeat, the value types every
  link kind carries.
- :mod:`.e2e`: AUTOSAR end-to-end protection, profile 2 (CRC8H2F + alive counter).
- :mod:`.reassembly`: frames -> ordered cycles, every drop counted by kind.
- :mod:`.links`: the seam (``JointStateSource``, ``PayloadSink``, counters) and the one table
  of link kinds (``LINKS``, ``open_link``: one opener signature, imported lazily).
- :mod:`.framed`: the base classes of the framed links (CAN, serial), both ends.
- :mod:`.can_link`: python-can buses by name (virtual, socketcan, slcan), the plug-in's link
  and the controller's port.
- :mod:`.serial_link`: msgpack over pyserial, framed with COBS + CRC32 (the wire:
  :mod:`.serial_wire`).
- :mod:`.franka_link`: a Franka Research 3 through pylibfranka (extra ``franka``; libfranka
  >= 0.10, exclusive FCI); :mod:`.franka_process` keeps pylibfranka in a child process (its
  ``read_once`` holds the interpreter lock while it waits).
- :mod:`.controller_port`: the controller's end of a link (the simulated controller,
  :mod:`deploy.simcell.controller`, stands behind it).
- :mod:`.slcan_adapter`, :mod:`.pty_pair`: an emulated slcan adapter on a pty, for
  cross-process tests on a machine without AF_CAN.
- :mod:`.faults`: drop, corrupt, duplicate, delay, silence.
- :mod:`.record`, :mod:`.replay`: bus logs with python-can's writers and readers.
- :mod:`.busload`: bus load (the bridge's speed: :mod:`deploy.bench.bridge`).
- :mod:`.checks`: the check suite every link kind passes (as :mod:`iem.checks` for
  estimators), on the harnesses of :mod:`.link_harness`.
- :mod:`.errors`: the bridge's errors under :class:`iem.errors.IemError`.
"""
