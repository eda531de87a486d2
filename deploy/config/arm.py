"""The ``[arm]`` section's checks across sections: the arm model a link implies and accepts,
its description read and checked, the gate's rated payload from it, and the end effector's
mass counted against that rating (:mod:`deploy.config.load` applies them as it loads)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path as FsPath
from typing import TYPE_CHECKING

from iem.errors import InvalidInputError

if TYPE_CHECKING:
    from .sections import ArmConfig, CellConfig, LinkConfig, Ros2Config


def _config_error(text: str):
    from .sections import ConfigError

    return ConfigError(text)


def arm_model_of(arm: ArmConfig, link: LinkConfig, ros2: Ros2Config, where: str) -> ArmConfig:
    """``[arm]`` with its model named: "" resolved by the link (:class:`ArmConfig`); a link
    kind that serves one arm model (the ``franka`` and ``program`` links: libfranka serves
    the FR3 only) refuses another."""
    from firmware_bridge.links import link_kind

    only = link_kind(link.kind).arm_model
    model = arm.model
    if not model:
        model = only or ("fr3" if link.kind == "ros2" and ros2.joints == "fr3" else "panda")
    if only is not None and model != only:
        raise _config_error(f"{where}: [arm] model = {model!r} with [link] kind = "
                            f"{link.kind!r}: libfranka (>= 0.10, pylibfranka) serves the FR3 "
                            f"only; set model = {only!r}, or serve a Panda through another "
                            "link")
    return replace(arm, model=model)


def with_description(cfg: CellConfig) -> CellConfig:
    """``cfg`` with its arm model read and checked (:mod:`sim.description`), the end
    effector's default taken from it, and the end effector's mass counted on the gate."""
    try:
        desc = cfg.arm.description()
    except (InvalidInputError, OSError) as exc:
        raise _config_error(f"{cfg.source}: [arm] model = {cfg.arm.model!r}: {exc}") from exc
    if not cfg.arm.end_effector:
        cfg = replace(cfg, arm=replace(cfg.arm, end_effector=desc.default_end_effector))
    ee = cfg.arm.end_effector
    if ee in ("franka_hand", "none") or FsPath(ee).is_absolute():
        cfg = with_end_effector(cfg)  # a relative tool file: once load_config found it
    return cfg


def check_rating(cfg: CellConfig) -> None:
    """Refuse a ``[gate] rated_mass_kg`` above the arm model's own rated payload (a named arm
    model's datasheet): a file cannot lift what the arm can carry."""
    from sim.description import BUILTINS

    builtin = BUILTINS.get(cfg.arm.model)
    if builtin is not None and cfg.gate.rated_mass_kg > builtin.rated_payload_kg:
        raise _config_error(f"{cfg.source}: [gate] rated_mass_kg = {cfg.gate.rated_mass_kg:g} "
                            f"is above the rated payload of [arm] model = {cfg.arm.model!r}, "
                            f"{builtin.rated_payload_kg:g} kg; valid is at most that (remove "
                            "the key to take it)")


def with_rated_payload(cfg: CellConfig) -> CellConfig:
    """``cfg`` whose gate's ``rated_mass_kg`` is the arm model's rated payload (a named arm
    model's datasheet); an arm model from a file has none: the key must be set."""
    from sim.description import BUILTINS

    builtin = BUILTINS.get(cfg.arm.model)
    if builtin is None:
        raise _config_error(f"{cfg.source}: [arm] model = {cfg.arm.model!r} gives no rated "
                            "payload; set [gate] rated_mass_kg to the arm maker's rated payload, "
                            "kg")
    return replace(cfg, gate=replace(cfg.gate, rated_mass_kg=builtin.rated_payload_kg))


def with_end_effector(cfg: CellConfig) -> CellConfig:
    """``cfg`` whose gate counts the declared end effector's mass against the rating."""
    from sim.end_effector import end_effector

    try:
        mass = end_effector(cfg.arm.end_effector).mass
    except (InvalidInputError, OSError) as exc:
        raise _config_error(f"{cfg.source}: [arm] end_effector = {cfg.arm.end_effector!r}: "
                            f"{exc}") from exc
    if mass + 0.01 > cfg.gate.rated_mass_kg:
        raise _config_error(f"{cfg.source}: [arm] end_effector weighs {mass:.3f} kg, which "
                            f"leaves no payload within [gate] rated_mass_kg = "
                            f"{cfg.gate.rated_mass_kg:g}")
    return replace(cfg, gate=replace(cfg.gate, end_effector_mass_kg=mass))
