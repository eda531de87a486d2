"""Making the initial model: bags and learners from the excitation path (``iem train``).

The tandem simulators of the configured training family (``cell`` by default: the paper's 77
container configurations and 77 random tools, :data:`sim.family.DEPLOY_FAMILY`) give
the samples at every state of the planned excitation path (the built-in one, or a path CSV);
the model's ``fit`` forms the initial bags and trains their learners. The model kinds are
those of :data:`iem.model_kinds.MODELS` that can learn online (``IEM``, ``IEM+phys``).

With an arm file (``--arm ARM``, from ``iem calibrate``) the tandem simulators are the
calibrated arm (:class:`sim.robot.ArmModel` with ``arm=``: its bodies, friction and
offsets), so the learners' samples are the real arm's; IEM+phys's regression and the
learners' reversal name the same arm by content (:func:`sim.arm.arm_spec`,
:func:`sim.coverage.reversal_spec`: ``...@arm:CRC32``, never a path); and the model file
records the arm's CRC, so that it is loaded only with that arm given
(:func:`iem.persistence.load_model`'s ``resources``) and refuses to run with another
(:func:`iem.persistence.check_arm`). A tool file declared as the end effector is the nominal
arm carrying it, referenced the same way.
"""

from __future__ import annotations

import time

from deploy.config import MODEL_KINDS
from iem.ensemble.budget import DEFAULT_BUDGET_BAGS
from iem.errors import InvalidInputError
from iem.model_kinds import DEFAULT_MODEL, MODELS, new_model
from iem.types import DEFAULT_BLOCK_FRAMES, NOMINAL_POINT_RATE_HZ, NOMINAL_RATE_HZ
from sim.family import DEPLOY_FAMILY

DEPLOY_ENSEMBLE = {"reversal": "sim.coverage:reversed_velocities",
                   "budget_bags": DEFAULT_BUDGET_BAGS}
"""The ensemble settings of a model the plug-in trains (``iem train``, ``train_if_missing``),
beyond the paper's rule: each bag's learner also trains on its own samples driven backwards
(:mod:`sim.coverage`; exact, on the model's arm: the first minute of ``iem bench longrun``,
seed 1, driven backwards read 0.021 kg off, against 0.20 kg with the random other velocities
of ``coverage`` and 1.5 kg with neither; a pose met at another speed is flagged out of
distribution instead), and at most 2,000 bags (beyond, a new bag takes a slot by
:class:`iem.ensemble.budget.BagBudget`'s probation policy; a model file of about 6 MB that loads in
0.3 s). The paper benchmark keeps the paper's rule."""


NOISE_SOURCES = ("arm", "sensor")
"""What IEM+phys takes as the error of its equations: ``arm``, the arm's own noise (measured
by ``iem calibrate`` into the arm file; :data:`iem.physics.torque_noise.NOMINAL_ARM_NOISE`, a
conservative default, for an arm that was not calibrated), the right choice on a real arm;
``sensor``, the sensor model's white noise alone: a simulated arm whose model is exact."""
NOISE_CHOICES = ("auto", *NOISE_SOURCES)
"""What a user may choose (``[arm] noise``, ``iem train --noise``): a source, or ``auto``
(:func:`noise_for`)."""


def noise_for(choice: str, arm_file) -> str:
    """The noise source of ``choice`` (one of :data:`NOISE_CHOICES`) for a model trained on
    ``arm_file`` (None or "": the nominal arm): ``auto`` is ``arm`` with an arm file (its
    measured noise) and ``sensor`` without. Without a calibration the sensor's noise is the
    one the data can test: on a real arm whose model errs, the model's own data verdict
    (``nis``) then holds the gate's writes (``data_disagree``), where the conservative
    default's wide band writes loads as biased as the arm's model; on an arm equal to its
    model it writes what the data show."""
    if choice not in NOISE_CHOICES:
        raise InvalidInputError(f"noise {choice!r}; valid are {', '.join(NOISE_CHOICES)}")
    if choice != "auto":
        return choice
    return "arm" if arm_file else "sensor"


def make_model(kind: str, seed: int = 0, rate_hz: float = NOMINAL_RATE_HZ, arm_file=None,
               end_effector=None, noise: str = "arm", arm=None,
               block_frames: int = DEFAULT_BLOCK_FRAMES, description=None, **params):
    """A fresh model of ``kind`` for joint states at ``rate_hz`` formed into block points of
    ``block_frames`` (:mod:`iem.signals.blocks`: the model works at ``rate_hz / block_frames``
    points per second); ``params`` go to its IEM;
    ``arm_file``: the arm file its physics uses (None: the nominal arm carrying
    ``end_effector``, :mod:`sim.end_effector`); ``noise``: one of :data:`NOISE_SOURCES`;
    ``arm``: :func:`load_arm_file`'s result for them, if the caller has it already;
    ``description``: the arm model (:mod:`sim.description`; None: the default)."""
    if kind not in MODEL_KINDS or kind not in MODELS:
        valid = [k for k in MODEL_KINDS if k in MODELS]
        raise InvalidInputError(f"model kind {kind!r} cannot be trained here; valid kinds are "
                                f"{', '.join(valid)}")
    from sim.coverage import reversal_spec

    if noise not in NOISE_SOURCES:
        raise InvalidInputError(f"noise {noise!r} is not valid; valid are "
                                f"{', '.join(NOISE_SOURCES)}")
    arm, _ = load_arm_file(arm_file, end_effector, description) if arm is None else arm
    # the nominal arm (a tool's or not) has no friction: its reversal is the plain one
    params = {**DEPLOY_ENSEMBLE, "reversal": reversal_spec(arm if arm_file else None),
              **params}
    if kind == "IEM+phys":  # the physics part filters at the link's rate; it holds an IEM
        from sim.arm import NOMINAL_DYNAMICS, arm_spec, nominal_spec

        extra = {"dynamics": NOMINAL_DYNAMICS}
        if arm_file is not None:
            extra["dynamics"] = arm_spec(arm)
        elif arm is not None:
            extra["dynamics"] = nominal_spec(end_effector, arm.description)
        point_rate = rate_hz / block_frames
        if noise == "arm":
            extra["torque_noise"] = arm_torque_noise(arm, point_rate)
        return new_model(kind, ensemble={"seed": seed, **params}, rate_hz=point_rate,
                         point_frames=block_frames, **extra)
    return new_model(kind, seed=seed, **params)


def check_model_family(model, family: str, where: str = "the model") -> None:
    """Refuse ``model`` if it was trained on another payload family than ``family`` (its new
    bags would be trained on one family's simulators, its old ones on another's)."""
    from deploy.config import ConfigError

    have = model.trained_family
    if have is not None and have != family:  # None: a model of unknown making (in memory)
        raise ConfigError(f"{where} was trained on the payload family {have!r}, the "
                          f"configuration's [model] family is {family!r}; set family = "
                          f"{have!r}, or make a model with 'iem train --family {family} --out "
                          f"MODEL'")


def check_model_arm(model, arm_record, where: str = "the model") -> None:
    """Refuse ``model`` unless it was trained for the arm ``arm_record``
    (:func:`iem.persistence.check_arm`) and every arm its factory specs reference by content
    (in its hyper-parameters, :meth:`iem.base.Estimator.params`: IEM+phys's dynamics, the
    learners' reversal: ``...@arm:CRC32``) is that arm."""
    from iem.errors import ModelFileError
    from iem.factories import referenced, specs_in
    from iem.persistence import check_arm

    check_arm(model, arm_record, where)
    for key, spec in specs_in(model.params()):
        ref = referenced(spec)
        if ref is not None and ref[0] == "arm" and (arm_record is None
                                                    or ref[1] != arm_record["crc32"]):
            raise ModelFileError(f"{where}: its {key} {spec!r} references the arm of CRC32 "
                                 f"{ref[1]:#010x}, not the arm it was trained for; retrain "
                                 "with 'iem train --arm ARM --out MODEL'")


def check_model_rate(model, rate_hz: float, block_frames: int, source: str,
                     where: str = "the model") -> None:
    """Refuse ``model`` if it was made for another point rate than ``rate_hz / block_frames``
    (:attr:`iem.base.Estimator.rate_hz`; None: a model without a signal filter, any rate),
    naming the ``iem train`` that makes one for ``source``'s joint states."""
    import math

    from iem.errors import ModelFileError

    made_for = model.rate_hz
    points = rate_hz / block_frames
    if made_for is not None and not math.isclose(made_for, points, rel_tol=1e-6):
        raise ModelFileError(f"{where} was made for {made_for:g} block points per second; "
                             f"{source} is at {rate_hz:g} Hz, in blocks of {block_frames} "
                             f"frames: {points:g}; make one for it with 'iem train --rate "
                             f"{rate_hz:g} --block-frames {block_frames} --out MODEL'")


def load_arm_file(arm_file, end_effector=None, description=None):
    """The arm of ``arm_file`` and its record for model files; without a file, the nominal
    arm of the arm model ``description`` (:mod:`sim.description`; None: the default)
    carrying ``end_effector`` (None: the arm model's default; ``(None, None)``: the default
    arm model's nominal arm with its default end effector). An ``end_effector`` or an arm
    model other than the arm file's is refused, naming both."""
    from sim.arm import ArmParams, arm_record, load_arm
    from sim.description import DEFAULT_ARM_MODEL, described
    from sim.end_effector import check_same, end_effector_of

    desc = described(description)
    if arm_file is None:
        ee = end_effector_of(end_effector, desc)
        if desc.name == DEFAULT_ARM_MODEL and ee.spec == desc.default_end_effector:
            return None, None
        arm = ArmParams.nominal(ee, desc)
        return arm, arm_record(arm)
    arm = load_arm(arm_file, desc)
    if end_effector:
        check_same(arm.end_effector, end_effector_of(end_effector, desc).label,
                   f"the arm file {arm_file}", "the configuration")
    return arm, arm_record(arm, arm_file)


def arm_torque_noise(arm, point_rate_hz: float = NOMINAL_POINT_RATE_HZ) -> dict:
    """What IEM+phys takes as its equations' error on ``arm`` (None: the nominal arm): the
    noise ``iem calibrate`` measured into the arm file, or the nominal arm's conservative
    default (:data:`iem.physics.torque_noise.NOMINAL_ARM_NOISE`) at the model's equation rate (one
    equation per block point). The measured noise's ``source`` names the arm by its content
    (``arm:CRC32``): the arm file's says what it was measured on, the recordings' paths
    included, and a model file holds data, never a path."""
    from dataclasses import replace

    from iem.physics.torque_noise import NOMINAL_ARM_NOISE

    if arm is not None and arm.noise is not None:
        return {**arm.noise, "source": f"measured by the calibration of arm:{arm.crc32:08x}"}
    return replace(NOMINAL_ARM_NOISE, rate_hz=point_rate_hz).to_dict()


def excitation(spec: str = "builtin", model=None):
    """The excitation path: ``builtin`` (:func:`sim.paths.excitation_path` of the arm model
    ``model``, None: the default) or a CSV file (checked against its limits)."""
    from sim.paths import excitation_path, load_path_csv

    if spec == "builtin":
        return excitation_path(model=model)
    return load_path_csv(spec, model=model)


def tandem_for(family: str, arm=None):
    """The tandem simulators of ``family`` on the arm ``arm`` (:class:`sim.arm.ArmParams`;
    None: the default arm model's nominal arm)."""
    from sim.family import family as family_payloads
    from sim.robot import ArmModel
    from sim.tandem import TandemSimulators

    return TandemSimulators(family_payloads(family), model=ArmModel(arm=arm))


def train_initial_model(kind: str = DEFAULT_MODEL, family: str = DEPLOY_FAMILY,
                        excitation_spec="builtin",
                        seed: int = 0, log=print, rate_hz: float = NOMINAL_RATE_HZ, arm_file=None,
                        end_effector=None, noise: str = "arm",
                        block_frames: int = DEFAULT_BLOCK_FRAMES, description=None, **params):
    """A new model of ``kind`` trained on the excitation path with ``family``'s payloads,
    for joint states arriving at ``rate_hz`` (1000 on the fd profile, 500 on classic) in
    block points of ``block_frames``, on
    the arm of ``arm_file`` (None: the nominal arm carrying ``end_effector``), with the
    equations' error of ``noise`` (:data:`NOISE_SOURCES`), on the arm model ``description``
    (:mod:`sim.description`; None: the default), whose limits the excitation path keeps."""
    from sim.robot import ArmModel

    arm, record = loaded = load_arm_file(arm_file, end_effector, description)
    model = make_model(kind, seed, rate_hz, arm_file=arm_file, end_effector=end_effector,
                       noise=noise, arm=loaded, block_frames=block_frames, **params)
    model.trained_arm = record
    model.trained_family = family
    kinematics = ArmModel(arm=arm, description=description)
    path = excitation(excitation_spec, kinematics)
    tandem = tandem_for(family, arm)
    t0 = time.perf_counter()
    model.fit(path.q, kinematics.flange_positions(path.q),
              lambda i: tandem.samples(path.q[i], path.dq[i], path.ddq[i]))
    log(f"trained {kind} on {path.name!r} ({path.duration:.0f} s, {len(tandem)} training "
        f"payloads{'' if arm_file is None else f', arm {arm_file}'}): {model.n_bags} bags "
        f"in {time.perf_counter() - t0:.1f} s")
    return model
