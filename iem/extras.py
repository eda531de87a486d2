"""The optional extras of ``iem-payload`` and a clear error where one is missing.

A robot-cell PC that only runs the service (``iem run``, ``iem calibrate``, ``iem identify``)
installs the core; the simulated Panda and the figures are extras (``pyproject.toml``):

- ``sim``: MuJoCo, the plant that stands in for the robot (:mod:`sim.plant`): ``iem demo``,
  ``iem sim-controller`` and the benchmarks that simulate;
- ``plots``: matplotlib, the figures of ``iem demo`` and ``iem bench paper``;
- ``ros2``, ``franka``: the ros2 and franka links, which name their extra themselves.

:func:`require` imports a module of an extra or raises :class:`~iem.errors.MissingExtraError`
saying what needs it and what to install; :func:`missing_extra` turns an import error that
escaped into that error (``deploy.cli`` does, so a command prints the hint, not a traceback).
"""

from __future__ import annotations

import importlib
from types import ModuleType

from .errors import MissingExtraError

EXTRAS: dict[str, str] = {
    "mujoco": "sim",
    "matplotlib": "plots",
    "cyclonedds": "ros2",
    "pylibfranka": "franka",
}
"""Top-level module -> the extra of ``iem-payload`` that installs it."""


def _message(module: str, what: str, cause: BaseException) -> str:
    extra = EXTRAS[module]
    return (f"{what} needs {module} (the '{extra}' extra), which cannot be imported here "
            f"({type(cause).__name__}: {cause}); install it with pip install "
            f"'iem-payload[{extra}]'")


def require(module: str, what: str) -> ModuleType:
    """``module`` (a key of :data:`EXTRAS`, or one of its submodules) imported; a
    :class:`~iem.errors.MissingExtraError` naming ``what`` needs it and the extra to install
    if it cannot be imported."""
    top = module.partition(".")[0]
    if top not in EXTRAS:
        raise KeyError(f"{top!r} is not the module of an extra; extras: {sorted(EXTRAS)}")
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise MissingExtraError(_message(top, what, exc)) from exc


def missing_extra(exc: BaseException, what: str = "this command") -> MissingExtraError | None:
    """The :class:`~iem.errors.MissingExtraError` for ``exc`` if it is the import error of an
    extra's module (:data:`EXTRAS`), else None."""
    if isinstance(exc, MissingExtraError):
        return exc
    name = getattr(exc, "name", None) if isinstance(exc, ImportError) else None
    top = (name or "").partition(".")[0]
    if top not in EXTRAS:
        return None
    return MissingExtraError(_message(top, what, exc))
