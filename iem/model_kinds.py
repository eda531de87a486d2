"""The model kinds: the table of estimator kinds a configuration or a model file names, and
the kind a plug-in runs unless told otherwise.

:data:`MODELS` maps a kind (an estimator's ``name``) to ``"module:Class"``; the module is
imported only when a model of that kind is made (:func:`new_model`) or read
(:func:`model_class`, for :mod:`iem.persistence`), as python-can does with its interfaces.
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping

from .errors import InvalidInputError, ModelFileError
from .migrations import current_path

MODELS: dict[str, str] = {
    "IEM": "iem.ensemble.model:IncrementalEnsemble",
    "old_IEM": "iem.baselines.old_iem:InPlaceEnsemble",
    "BEM": "iem.baselines.bem:BatchEnsemble",
    "LS": "iem.baselines.least_squares:RecursiveLeastSquares",
    "IEM+phys": "iem.physics.model:PhysicsInformedEnsemble",
}
"""Estimator kinds that can be loaded: ``name -> "module:Class"``. Add one line per kind (or
call :func:`register_model`); the module is imported only when a file of that kind is read."""

DEFAULT_MODEL = "IEM+phys"
"""The kind a plug-in runs unless its configuration names another (:func:`new_model`): the
most accurate one, with uncertainty, physical consistency and payload-change detection."""


def register_model(kind: str, target: str) -> None:
    """Make files of ``kind`` loadable by :func:`iem.persistence.load_model` (``target``:
    ``"module:Class"``)."""
    if not isinstance(kind, str) or not kind:
        raise ValueError(f"model kind must be a non-empty str, got {kind!r}")
    if not isinstance(target, str) or target.count(":") != 1:
        raise ValueError(f"model target must be 'module:Class', got {target!r}")
    MODELS[kind] = target


def new_model(kind: str = DEFAULT_MODEL, **params):
    """A fresh, untrained estimator of ``kind`` (a key of :data:`MODELS`), built with
    ``params`` (its constructor's hyper-parameters): how a configuration selects a model.

    Raises:
        InvalidInputError: the kind is unknown or cannot be imported, or a parameter is not
            one the kind accepts.
    """
    if kind not in MODELS:
        raise InvalidInputError(f"unknown model kind {kind!r}; valid kinds are "
                                f"{', '.join(sorted(MODELS))}")
    module_name, _, class_name = MODELS[kind].partition(":")
    try:
        cls = getattr(importlib.import_module(module_name), class_name)
    except (ImportError, AttributeError) as exc:
        raise InvalidInputError(f"model kind {kind!r} ({MODELS[kind]}) cannot be imported: "
                                f"{exc}") from exc
    try:
        return cls(**params)
    except TypeError as exc:
        raise InvalidInputError(f"model kind {kind!r} does not take these parameters "
                                f"{sorted(params)}: {exc}") from exc


def model_class(kind: str, registry: Mapping[str, str], where: str):
    """The class ``registry`` names for ``kind`` (a model file's, read at ``where``), imported.

    Raises:
        ModelFileError: the kind is not in ``registry``, or its class cannot be imported.
    """
    if kind not in registry:
        raise ModelFileError(f"{where} holds a model of unknown kind {kind!r}; known kinds: "
                             f"{', '.join(sorted(registry)) or '(none)'}")
    target = registry[kind]
    try:
        module_name, _, class_name = current_path(str(target)).partition(":")
        return getattr(importlib.import_module(module_name), class_name)
    except (ImportError, AttributeError, ValueError, InvalidInputError) as exc:
        raise ModelFileError(f"{where} holds a model of kind {kind!r}, registered as "
                             f"{target!r}, which cannot be imported: {exc}") from exc
