"""The plug-in's configuration, ``cell.toml``: read, checked, and turned into settings.

Every key is documented in ``deploy/cell.toml`` (the example a cell starts from). Any error
names the key, the value found and what would be valid; unknown keys are errors too, so a
typo never silently falls back to a default.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field, fields
from pathlib import Path as FsPath

from iem.errors import InvalidInputError

from .gate import GateConfig


class ConfigError(InvalidInputError):
    """``cell.toml`` is missing, not TOML, or has a key with an invalid value."""


LINK_KINDS = ("virtual", "socketcan", "slcan", "serial", "franka", "replay")
PROFILES = ("fd", "classic")
MODEL_KINDS = ("IEM", "IEM+phys")
LOG_FORMATS = ("json", "text")
LOG_LEVELS = ("debug", "info", "warning", "error")
STATUS_MODES = ("auto", "on", "off")


@dataclass(frozen=True)
class LinkConfig:
    """Where the joint states come from and the loads go (``[link]``)."""

    kind: str = "virtual"
    channel: str = "iem"
    profile: str = "fd"
    silence_timeout_s: float = 0.1


@dataclass(frozen=True)
class ModelConfig:
    """The model file and how a new model is made (``[model]``)."""

    path: str = "model.msgpack"
    kind: str = "IEM+phys"
    checkpoint_period_s: float = 60.0
    train_if_missing: bool = True
    family: str = "paper"
    excitation: str = "builtin"
    seed: int = 0
    arm: str = ""
    """The arm file from ``iem calibrate`` (empty: the nominal arm); the model must have
    been trained for it (``iem train --arm``)."""


@dataclass(frozen=True)
class EstimateConfig:
    """The online estimate (``[estimate]``)."""

    smoothing_tau_s: float = 0.2
    filter_cutoff_hz: float = 50.0
    learn: bool = True
    max_lag_s: float = 0.1


@dataclass(frozen=True)
class LogConfig:
    """Logging and the terminal status line (``[log]``)."""

    level: str = "info"
    format: str = "json"
    status_line: str = "auto"
    status_period_s: float = 0.25


@dataclass(frozen=True)
class CellConfig:
    """Everything ``iem run`` needs."""

    link: LinkConfig = field(default_factory=LinkConfig)
    model: ModelConfig = field(default_factory=ModelConfig)
    estimate: EstimateConfig = field(default_factory=EstimateConfig)
    gate: GateConfig = field(default_factory=GateConfig)
    log: LogConfig = field(default_factory=LogConfig)
    source: str = "<defaults>"


SECTIONS = {"link": LinkConfig, "model": ModelConfig, "estimate": EstimateConfig,
            "gate": GateConfig, "log": LogConfig}

# keys with a restricted set of values, and numeric ranges (lo, hi, lo inclusive)
CHOICES = {("link", "kind"): LINK_KINDS, ("link", "profile"): PROFILES,
           ("model", "kind"): MODEL_KINDS, ("log", "format"): LOG_FORMATS,
           ("log", "level"): LOG_LEVELS, ("log", "status_line"): STATUS_MODES}
MAY_BE_EMPTY = {("model", "arm")}  # string keys whose empty value means "none"
RANGES = {
    ("link", "silence_timeout_s"): (0.005, 60.0),
    ("model", "checkpoint_period_s"): (1.0, 86400.0),
    ("estimate", "smoothing_tau_s"): (0.0, 60.0),
    ("estimate", "filter_cutoff_hz"): (1.0, 499.0),
    ("estimate", "max_lag_s"): (0.0, 60.0),
    ("log", "status_period_s"): (0.05, 60.0),
    ("gate", "rated_mass_kg"): (0.01, 3.0),
    ("gate", "max_com_radius_m"): (0.001, 1.0),
    ("gate", "stable_window_s"): (0.0, 60.0),
    ("gate", "stable_mass_kg"): (0.0, 3.0),
    ("gate", "stable_com_m"): (0.0, 1.0),
    ("gate", "min_change_mass_kg"): (0.0, 3.0),
    ("gate", "min_change_com_m"): (0.0, 1.0),
    ("gate", "max_rate_hz"): (0.001, 100.0),
    ("gate", "ack_timeout_s"): (0.01, 60.0),
    ("gate", "ack_retry_s"): (0.1, 3600.0),
    ("gate", "decision_period_s"): (0.001, 10.0),
}


def _check(section: str, key: str, value, default, where: str):
    name = f"{where}: [{section}] {key}"
    expected = type(default)
    if expected is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{name} = {value!r} must be true or false")
        return value
    if expected is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{name} = {value!r} must be an integer")
        return value
    if expected is float:
        if isinstance(value, bool) or not isinstance(value, int | float) \
                or not math.isfinite(value):
            raise ConfigError(f"{name} = {value!r} must be a finite number")
        value = float(value)
        lo, hi = RANGES.get((section, key), (-math.inf, math.inf))
        if not lo <= value <= hi:
            raise ConfigError(f"{name} = {value!r} is out of range; valid is [{lo:g}, {hi:g}]")
        return value
    if expected is str:
        if isinstance(value, str) and not value and (section, key) in MAY_BE_EMPTY:
            return value
        if not isinstance(value, str) or not value:
            raise ConfigError(f"{name} = {value!r} must be a non-empty string")
        choices = CHOICES.get((section, key))
        if choices and value not in choices:
            raise ConfigError(f"{name} = {value!r} is not valid; valid values are "
                              f"{', '.join(repr(c) for c in choices)}")
        return value
    raise ConfigError(f"{name}: unsupported setting type")  # pragma: no cover


def config_from_dict(doc: dict, where: str = "config") -> CellConfig:
    """Check a parsed ``cell.toml`` and build the settings (missing keys take defaults)."""
    unknown = sorted(set(doc) - set(SECTIONS))
    if unknown:
        raise ConfigError(f"{where}: unknown section(s) {unknown}; valid sections are "
                          f"{', '.join(f'[{s}]' for s in SECTIONS)}")
    built = {}
    for section, cls in SECTIONS.items():
        table = doc.get(section, {})
        if not isinstance(table, dict):
            raise ConfigError(f"{where}: [{section}] must be a table, got {table!r}")
        defaults = cls()
        names = {f.name for f in fields(cls)}
        bad = sorted(set(table) - names)
        if bad:
            raise ConfigError(f"{where}: unknown key(s) {bad} in [{section}]; valid keys are "
                              f"{', '.join(sorted(names))}")
        values = {k: _check(section, k, v, getattr(defaults, k), where)
                  for k, v in table.items()}
        built[section] = cls(**{**{f.name: getattr(defaults, f.name) for f in fields(cls)},
                                **values})
    link = built["link"]
    if link.kind == "replay" and not FsPath(link.channel).suffix:
        raise ConfigError(f"{where}: [link] channel = {link.channel!r}: a replay channel is "
                          "a log file (.blf, .log, .asc or .trc)")
    return CellConfig(**built, source=where)


def load_config(path) -> CellConfig:
    """Read and check ``cell.toml``; relative model paths are taken from the file's folder."""
    path = FsPath(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the configuration: "
                          f"{exc.strerror or exc}") from exc
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from exc
    cfg = config_from_dict(doc, where=str(path))
    model_path = FsPath(cfg.model.path)
    arm_path = FsPath(cfg.model.arm)
    if not model_path.is_absolute() or (cfg.model.arm and not arm_path.is_absolute()):
        model = ModelConfig(**{**{f.name: getattr(cfg.model, f.name)
                                  for f in fields(ModelConfig)},
                               "path": str(path.parent / model_path),
                               "arm": str(path.parent / arm_path) if cfg.model.arm else ""})
        cfg = CellConfig(link=cfg.link, model=model, estimate=cfg.estimate, gate=cfg.gate,
                         log=cfg.log, source=cfg.source)
    return cfg
