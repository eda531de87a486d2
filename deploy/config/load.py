"""Reading ``cell.toml``: every key checked against the sections' fields and the tables of
:mod:`deploy.config.sections`, the ``[arm]`` section's checks across sections applied
(:mod:`deploy.config.arm`), and the settings built.

Every key is documented in ``deploy/cell.toml`` (the example a cell starts from). Any error
names the key, the value found and what would be valid; unknown keys are errors too, so a
typo never silently falls back to a default. The file is read within bounds, as every TOML
file a user hands over (:func:`iem.user_files.read_toml`: a regular file of UTF-8 text, at
most 1 MB, nested at most 32 deep), so no file named here can hang or crash the start.
"""

from __future__ import annotations

import math
from dataclasses import fields, replace
from pathlib import Path as FsPath

from iem.errors import InvalidInputError
from iem.user_files import read_toml

from .arm import (
    arm_model_of,
    check_rating,
    with_description,
    with_end_effector,
    with_rated_payload,
)
from .sections import (
    CHOICES,
    DERIVED_GATE_KEYS,
    INT_RANGES,
    MAY_BE_EMPTY,
    RANGES,
    RETIRED_GATE_KEYS,
    ROS_NAME,
    ROS_NAMES,
    SECTIONS,
    CellConfig,
    ConfigError,
    ModelConfig,
)


def _ros_name_error(name: str, value: str) -> str | None:
    if ROS_NAME.fullmatch(value):
        return None
    return (f"{name} = {value!r} is not a fully qualified ROS 2 name; valid: '/' then "
            "segments of letters, digits and '_' (not starting with a digit) separated by "
            "'/', e.g. '/franka/joint_states'")

def _check(section: str, key: str, value, default, where: str):
    name = f"{where}: [{section}] {key}"
    expected = type(default)
    if expected is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{name} = {value!r} must be true or false")
        return value
    if expected is int:
        lo, hi = INT_RANGES.get((section, key), (-(2**63), 2**63 - 1))
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{name} = {value!r} must be an integer from {lo} to {hi}")
        if not lo <= value <= hi:
            raise ConfigError(f"{name} = {value!r} is out of range; valid is an integer "
                              f"from {lo} to {hi}")
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
    if expected is tuple or ((section, key) == ("ros2", "joints") and isinstance(value, list)):
        n = 7 if (section, key) == ("ros2", "joints") else None
        if not isinstance(value, list) or not all(isinstance(v, str) and v for v in value) \
                or (n is not None and (len(value) != n or len(set(value)) != n)):
            what = f"{n} distinct non-empty strings" if n else "non-empty strings"
            raise ConfigError(f"{name} = {value!r} must be a list of {what}")
        return tuple(value)
    if expected is str:
        if isinstance(value, str) and not value and (section, key) in MAY_BE_EMPTY:
            return value
        if not isinstance(value, str) or not value:
            raise ConfigError(f"{name} = {value!r} must be a non-empty string")
        if (section, key) in ROS_NAMES and (error := _ros_name_error(name, value)):
            raise ConfigError(error)
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
        names = {f.name for f in fields(cls)} - (set(DERIVED_GATE_KEYS) if section == "gate"
                                                 else set())
        retired = sorted(set(table) & set(RETIRED_GATE_KEYS)) if section == "gate" else []
        if retired:
            raise ConfigError(f"{where}: [gate] {', '.join(retired)}: not a setting of this gate: "
                              f"{RETIRED_GATE_KEYS[retired[0]]}; remove "
                              f"{'it' if len(retired) == 1 else 'them'}")
        bad = sorted(set(table) - names)
        if bad:
            raise ConfigError(f"{where}: unknown key(s) {bad} in [{section}]; valid keys are "
                              f"{', '.join(sorted(names))}")
        values = {k: _check(section, k, v, getattr(defaults, k), where)
                  for k, v in table.items()}
        try:
            built[section] = cls(**{**{f.name: getattr(defaults, f.name) for f in fields(cls)},
                                    **values})
        except InvalidInputError as exc:  # a check across keys (GateConfig's own)
            raise ConfigError(f"{where}: [{section}] {exc}") from exc
    link = built["link"]
    if link.kind == "ros2" and "channel" not in doc.get("link", {}):
        link = built["link"] = replace(link, channel="/franka/joint_states")
    if link.kind == "ros2" and (error := _ros_name_error(f"{where}: [link] channel",
                                                         link.channel)):
        raise ConfigError(error + " (for kind 'ros2' the channel is the JointState topic)")
    if link.kind == "replay" and not FsPath(link.channel).suffix:
        raise ConfigError(f"{where}: [link] channel = {link.channel!r}: a replay channel is "
                          "a log file (.blf, .log, .asc or .trc)")
    built["arm"] = arm_model_of(built["arm"], link, built["ros2"], where)
    ee = built["arm"].end_effector
    if ee not in ("", "franka_hand", "none") and not ee.endswith((".toml", ".json")):
        raise ConfigError(f"{where}: [arm] end_effector = {ee!r} is not valid; valid are "
                          "'franka_hand', 'none', the path of a payload-style .toml file of "
                          "the tool on the flange, or Franka Desk's endeffector-config.json")
    cfg = CellConfig(**built, source=where)
    if "rated_mass_kg" not in doc.get("gate", {}):
        cfg = with_rated_payload(cfg)
    else:
        check_rating(cfg)
    if not FsPath(cfg.arm.model).suffix or FsPath(cfg.arm.model).is_absolute():
        cfg = with_description(cfg)  # a relative description file: once load_config found it
    return cfg

def load_config(path) -> CellConfig:
    """Read and check ``cell.toml``; relative model paths are taken from the file's folder."""
    path = FsPath(path)
    doc = read_toml(path, "configuration file", ConfigError)
    cfg = config_from_dict(doc, where=str(path))
    model_path = FsPath(cfg.model.path)
    arm_path = FsPath(cfg.model.arm)
    if not model_path.is_absolute() or (cfg.model.arm and not arm_path.is_absolute()):
        model = ModelConfig(**{**{f.name: getattr(cfg.model, f.name)
                                  for f in fields(ModelConfig)},
                               "path": str(path.parent / model_path),
                               "arm": str(path.parent / arm_path) if cfg.model.arm else ""})
        cfg = replace(cfg, model=model)
    model = cfg.arm.model
    if FsPath(model).suffix and not FsPath(model).is_absolute():
        cfg = replace(cfg, arm=replace(cfg.arm, model=str(path.parent / model)))
        cfg = with_description(cfg)  # the description file, found from the file's folder
    ee = cfg.arm.end_effector
    if ee not in ("franka_hand", "none") and not FsPath(ee).is_absolute():
        cfg = replace(cfg, arm=replace(cfg.arm, end_effector=str(path.parent / ee)))
    if ee not in ("franka_hand", "none"):
        cfg = with_end_effector(cfg)  # the tool file, found from the file's folder
    initial = cfg.estimate.initial_payload
    if initial and not FsPath(initial).is_absolute():
        cfg = replace(cfg, estimate=replace(cfg.estimate,
                                            initial_payload=str(path.parent / initial)))
    return cfg
