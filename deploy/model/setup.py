"""What the service starts from: the model of the configuration, checked against the link's
rate and the configured arm and family, a known payload to start from, and the link's wire
range check for the gate.

:func:`load_or_train_model` loads ``[model] path`` (removing the temporary files of an
interrupted save first) with the arm the configuration gives (``[model] arm``, ``[arm]
end_effector``: a model file names its arm by content and is loaded only with it,
:func:`iem.persistence.load_model`) and refuses a model of another kind than ``[model]
kind``, or made for another point rate than the link's rate over ``[estimate]
block_frames`` (:attr:`iem.base.Estimator.rate_hz`); without a file it trains one on the excitation
path if ``train_if_missing`` (saved to ``[model] path``, but over a recorded link, whose
replay learns in memory only). :func:`start_from_file` makes IEM+phys start from
``[estimate] initial_payload``.

Every file ``cell.toml`` names is the configuration's: one that is missing or cannot be read
(``[model] path`` without ``train_if_missing``, ``[model] arm``, a model for another arm)
is a :class:`deploy.config.ConfigError` naming the key (``iem run`` exits 78: a restart
cannot fix it).
"""

from __future__ import annotations

import contextlib
import logging
import math
from pathlib import Path as FsPath

from deploy.config import CellConfig, ConfigError
from iem.atomic_file import remove_stale_temporaries
from iem.errors import InvalidInputError, ModelFileError
from iem.persistence import load_model, save_model

log = logging.getLogger("iem.service")


def link_rate(config: CellConfig) -> float:
    """Joint states per second the configured link delivers, as its kind and wire profile say
    (:func:`firmware_bridge.links.rate_hz`)."""
    from firmware_bridge.links import rate_hz

    return rate_hz(config.link.kind, config.link.profile)


def point_rate(config: CellConfig) -> float:
    """Block points per second the estimator works at: the link's rate over ``[estimate]
    block_frames``."""
    return link_rate(config) / block_frames_of(config)


def block_frames_of(config: CellConfig, rate_hz: float | None = None) -> int:
    """Frames per block point: ``[estimate] block_frames``, or (0) the rate over 100
    (:func:`iem.signals.rate.block_frames_for`: about 100 points a second); ``rate_hz``:
    the joint states a second the link delivers (None: the configured link's)."""
    from iem.signals.rate import block_frames_for

    rate = link_rate(config) if rate_hz is None else rate_hz
    return config.estimate.block_frames or block_frames_for(rate)


@contextlib.contextmanager
def file_of(config: CellConfig, key: str, value: str):
    """Errors of reading the file that ``key`` (``"[model] arm"``) names are configuration
    errors naming the key and ``value``: a restart cannot fix a missing or unreadable file."""
    try:
        yield
    except ConfigError:
        raise
    except (InvalidInputError, ModelFileError) as exc:  # a bad model, arm file, end effector
        raise ConfigError(f"{config.source}: {key} = {value!r}: {exc}") from exc


def model_resources(config: CellConfig) -> dict:
    """What the configured model runs on, for :func:`iem.persistence.load_model`:
    ``{"arm": ...}``, the arm of ``[model] arm`` or the nominal arm carrying ``[arm]
    end_effector`` (None: the nominal arm with the Franka Hand)."""
    from .training import load_arm_file

    with file_of(config, "[model] arm", config.model.arm):
        arm, _ = load_arm_file(config.model.arm or None, config.arm.end_effector,
                               config.arm.description())
    return {"arm": arm}


def load_or_train_model(config: CellConfig, resources: dict | None = None):
    """The model of the configuration: its file, loaded with ``resources`` (None: the
    configuration's, :func:`model_resources`), or a new one trained on the excitation path."""
    mc = config.model
    path = FsPath(mc.path)
    for stale in remove_stale_temporaries(path):  # left by a save that was killed
        log.info("removed %s, the temporary file of an interrupted save", stale,
                 extra={"event": "stale_temporary_removed", "path": str(stale)})
    rate, frames = link_rate(config), block_frames_of(config)
    if path.exists():
        resources = model_resources(config) if resources is None else resources
        with file_of(config, "[model] path", mc.path):
            model = load_model(path, resources=resources)
        if model.name != mc.kind:
            raise ConfigError(f"model file {path} holds a model of kind {model.name!r}, the "
                              f"configuration's [model] kind is {mc.kind!r}; set kind = "
                              f"{model.name!r}, or make a model of that kind with 'iem train "
                              f"--kind {mc.kind} --out {path}'")
        made_for = model.rate_hz  # None: no signal filter, any rate
        if made_for is not None and not math.isclose(made_for, rate / frames):
            raise ConfigError(
                f"model file {path} was made for {made_for:g} block points per second; the "
                f"[link] profile {config.link.profile!r} delivers {rate:g} joint states per "
                f"second, in blocks of [estimate] block_frames = {frames}: "
                f"{rate / frames:g}; make one for this link with 'iem train --out {path} "
                f"--rate {rate:g} --block-frames {frames}'")
        log.info("loaded model %s: %s with %d bags", path, model.name, model.n_bags,
                 extra={"event": "model_loaded", "path": str(path), "bags": model.n_bags})
        return model
    if not mc.train_if_missing:
        raise ConfigError(f"{config.source}: [model] path = {mc.path!r}: the model file does "
                          "not exist and [model] train_if_missing is false; create one with "
                          "'iem train --out FILE' or set train_if_missing = true")
    from .training import noise_for, train_initial_model

    model = train_initial_model(mc.kind, mc.family, mc.excitation, mc.seed,
                                log=lambda msg: log.info(msg, extra={"event": "trained"}),
                                rate_hz=rate, block_frames=frames, arm_file=mc.arm or None,
                                end_effector=config.arm.end_effector,
                                noise=noise_for(config.arm.noise, mc.arm),
                                description=config.arm.description())
    from firmware_bridge.links import link_kind

    if link_kind(config.link.kind).recorded:  # a replay never writes the model
        log.info("trained a model in memory: over a recorded link the model file %s is not "
                 "written", path, extra={"event": "trained_in_memory"})
        return model
    path.parent.mkdir(parents=True, exist_ok=True)
    save_model(model, path)
    log.info("saved the new model to %s", path, extra={"event": "model_saved"})
    return model


def checked_model(config: CellConfig, model=None):
    """``(model, arm)``: ``model`` (None: :func:`load_or_train_model`) checked against the
    configured arm file and payload family, started from ``[estimate] initial_payload`` if
    one is set, else, when restarted from its file, holding what it knew of the payload as
    unverified (:meth:`iem.base.Estimator.distrust`); ``arm`` the configured arm (None: the
    nominal one).

    Raises:
        ConfigError: a file it names is missing or cannot be read, the model was made for
            another arm or trained on another payload family.
    """
    from .training import check_model_arm, check_model_family, load_arm_file

    with file_of(config, "[model] arm", config.model.arm):
        arm, arm_record = load_arm_file(config.model.arm or None, config.arm.end_effector,
                                        config.arm.description())
    path = FsPath(config.model.path)
    restored = model is None and path.exists()  # a restart from the last checkpoint
    if model is None:
        model = load_or_train_model(config, {"arm": arm})
    where = f"the model {path}" if path.exists() else "the model"
    with file_of(config, "[model] path", config.model.path):
        check_model_arm(model, arm_record, where=where)
    check_model_family(model, config.model.family, where=where)
    if config.estimate.initial_payload:
        with file_of(config, "[estimate] initial_payload", config.estimate.initial_payload):
            start_from_file(model, config.estimate.initial_payload)
    elif restored:  # the payload may have been swapped while the plug-in was down
        model.distrust()
        log.info("restarted from %s: its payload is unverified until the live data have "
                 "tested it", path, extra={"event": "restart_unverified", "path": str(path)})
    return model, arm


INITIAL_STD = (0.01, 0.002, 0.002, 0.002, 0.002, 0.002, 0.002, 0.002, 0.002, 0.002)
"""The prior's standard deviations of an initial payload file without ``phi_std`` (kg, kg·m,
kg·m²): what an offline identification on a short motion reaches at least."""


def start_from_file(model, path: str) -> None:
    """Make ``model`` start from the payload file at ``path`` (``[estimate]
    initial_payload``): its first estimate and prior."""
    from deploy.config import ConfigError
    from sim.payload import load_payload_prior

    if not model.starts_from_payload:
        raise ConfigError(f"[estimate] initial_payload = {path!r}: the {model.name} model "
                          "cannot start from a payload (it keeps no payload state); valid "
                          "with [model] kind = 'IEM+phys'")
    payload, std = load_payload_prior(path)
    model.start_from(payload.to_phi(), INITIAL_STD if std is None else std)
    log.info("starting from the payload file %s: %.4f kg at [%.4f, %.4f, %.4f] m; writes wait "
             "until the live data have tested it", path, payload.mass, *payload.com,
             extra={"event": "initial_payload", "path": path})
