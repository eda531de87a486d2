"""One root for every error the project raises on purpose.

Each error says what was wrong and what would have been valid. Packages add their own
subclasses (``firmware_bridge`` its decode and link errors, ``deploy`` its config errors), all
under :class:`IemError`, so a caller can catch the project's errors without catching bugs.
"""

from __future__ import annotations


class IemError(Exception):
    """Root of all errors raised on purpose by this project."""


class InvalidInputError(IemError, ValueError):
    """An argument or a value read from outside has the wrong shape, type or range."""


class PayloadError(InvalidInputError):
    """A payload is physically impossible, or a payload file is malformed."""


class PathError(InvalidInputError):
    """A joint path breaks a joint limit, or a path file is malformed."""


class ModelFileError(IemError):
    """A saved model file is missing, truncated, corrupt or of an unknown schema version."""


class CheckFailed(IemError, AssertionError):
    """A component broke one of the shared check suites (an estimator :mod:`iem.checks`'s, a
    link :mod:`firmware_bridge.checks`'s); the message names the check, what was expected
    and what was found."""


class MissingExtraError(IemError, ImportError):
    """A part of the project that needs an optional extra (the simulator, the plots) was used
    where that extra is not installed; the message names the ``pip install`` that adds it
    (:func:`iem.extras.require`)."""
