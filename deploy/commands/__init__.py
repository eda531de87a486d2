"""A module per ``iem`` command, each ``configure(parser)`` (its arguments) and
``run(args) -> int`` (its exit status), loaded by name when the command runs (the table in
:mod:`deploy.cli`). A command holds its command line; what a lower room needs lives there.
"""
