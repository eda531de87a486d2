"""Every benchmark: a module per ``iem bench`` command (the table in :mod:`deploy.cli`) and
the parts they share; the write-back's benchmark has a folder of its own
(:mod:`deploy.bench.writeback`). They measure the learning core in the simulation, the
simulation's and the bridge's speed, and the plug-in end to end, under faults and on a real
recording; they may import every package, so the library packages hold only what a cell
runs."""
