"""Model-file schema versions, the steps between them, and the table of moved names.

A model file records the schema ``version`` it was written at (:mod:`iem.persistence`), and
is always written at :data:`VERSION`. Each change to what a model's state holds, or means,
adds a version and one step here: a pure function ``step(kind, state, records=None) ->
state`` from version ``n`` to ``n + 1`` (:data:`STEPS`), on the unpacked plain data (dicts,
lists, numbers, str) of a model of ``kind`` (the file's ``kind``), given the maps the file
holds beside the state (``records``: ``{"arm": <its arm record or None>}``), that returns
the new state and leaves its argument as it was. :func:`migrate` applies the steps from a
file's version to :data:`VERSION` in order, so that a model's ``from_state`` reads the
newest layout alone. A step writes out the values and rules that held at its version (it
imports no model code, whose defaults may change later); a kind it does not name passes
unchanged (the arm file, :mod:`sim.arm`, shares the versions: its state is its identity,
recorded by CRC in the models trained for it, so no step may change it).

The steps:

1 -> 2  (:func:`fill_version_1`) every version-1 state in the full version-1 layout: the
        fields that version-1 files written before them lack get the values the loaders
        assumed for such files.
2 -> 3  (:func:`equations_per_point`) the estimators take block points (:mod:`iem.signals.blocks`),
        each the mean of some frames, instead of frames: IEM+phys, whose physics averaged
        ``update_every > 1`` frames itself, now takes ``rate_hz := rate_hz /
        update_every``, ``update_every := 1`` and ``point_frames := update_every`` (the same
        equations and noise; its ``torque_noise`` is measured at that rate already), and
        saves when its posterior is refreshed next (``stale``, ``since_refresh``,
        ``undetermined``: as version-2 code loaded a file, fresh, nothing counted, every
        group undetermined until the next refresh); LS,
        which filtered frames, takes the default block of 10 frames: ``rate_hz := rate_hz
        / 10``, ``point_frames := 10`` (its filter state restarts).

3 -> 4  (:func:`content_references`) a model names the files it was made with by content,
        never by path (:mod:`iem.factories`): a spec ``...@/path/arm.msgpack`` of the
        physics' dynamics or the learners' reversal becomes ``...@arm:CRC32``, the arm the
        file records (its ``arm`` record, :func:`iem.persistence.check_arm`); the nominal
        arm carrying a tool file (``sim.arm:nominal_dynamics@/path/tool.toml``) becomes
        ``sim.arm:arm_dynamics@arm:CRC32`` too, that arm as the file records it (the record
        of a model trained with a tool is the nominal arm carrying it).

4 -> 5  (:func:`learner_named`) an ensemble's hyper-parameters name the learner that trains
        its bags (:mod:`iem.ensemble.learners`): a version-4 file's are ``"sgd"``.

5 -> 6  (:func:`candidate_kept`) an IEM+phys state holds the posterior before an alarm
        while the data have not chosen between it and the new one (``candidate``): a
        version-5 file kept none (None; loaded, it held none either).

A file names its kind's class (:data:`iem.model_kinds.MODELS`, ``"module:Class"``) and the
factories in its state (``coverage``, ``reversal``, ``dynamics``: names of
:data:`iem.factories.FACTORIES`). These go through :data:`ALIASES` at load
(:func:`current_path`, :func:`with_current_paths`): a name that changes adds one row, old ->
new, and the files that hold it keep loading (and hold the new one when saved again).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

from .errors import InvalidInputError
from .factories import SPEC_KEYS

Step = Callable[..., dict]
"""``step(kind, state, records=None) -> state``."""

ALIASES: dict[str, str] = {
    # the nominal arm's dynamics: one factory for every arm model (sim.description)
    "sim.robot:panda_dynamics": "sim.arm:arm_dynamics",
    # iem's modules into sub-packages: the estimators' classes (iem.model_kinds.MODELS)
    "iem.ensemble:IncrementalEnsemble": "iem.ensemble.model:IncrementalEnsemble",
    "iem.physics:PhysicsInformedEnsemble": "iem.physics.model:PhysicsInformedEnsemble",
    "iem.old_iem": "iem.baselines.old_iem",
    "iem.bem": "iem.baselines.bem",
    "iem.least_squares": "iem.baselines.least_squares",
}
"""Module paths that moved: ``"old.module" -> "new.module"`` (every name in it) or
``"old.module:name" -> "new.module:name"`` (one name). A row may name a path that moved
again (rows chain). Add a row when a module that model files name moves."""

def current_path(path: str) -> str:
    """``path`` (``"module"``, ``"module:name"``, optionally ``@ARG``) where it lives now:
    through :data:`ALIASES` until no row applies (the ``@ARG`` is kept).

    Raises:
        InvalidInputError: the rows form a cycle.
    """
    target, at, arg = path.partition("@")
    seen = {target}
    while True:
        module, colon, name = target.partition(":")
        if target in ALIASES:
            target = ALIASES[target]
        elif module in ALIASES:
            target = ALIASES[module] + colon + name
        else:
            return target + at + arg
        if target in seen:
            raise InvalidInputError(f"the module aliases of {path!r} form a cycle through "
                                    f"{target!r}")
        seen.add(target)


def with_current_paths(state: dict) -> dict:
    """``state`` with the factory specs (:data:`SPEC_KEYS`) of its maps, nested maps
    included, at their :func:`current_path`; the maps on the way are copied, the rest is
    shared (the argument is left as it was)."""
    out = None
    for key, value in state.items():
        new = value
        if isinstance(value, dict):
            new = with_current_paths(value)
        elif key in SPEC_KEYS and isinstance(value, str):
            new = current_path(value)
        if new is not value:
            out = dict(state) if out is None else out
            out[key] = new
    return state if out is None else out


# -- 1 -> 2 ------------------------------------------------------------------------------
def _zeros(*shape: int) -> list:
    if len(shape) == 1:
        return [0.0] * shape[0]
    return [_zeros(*shape[1:]) for _ in range(shape[0])]


def _filled(state: Mapping, defaults: Mapping) -> dict:
    """A copy of ``state`` with each key of ``defaults`` it lacks set to the default."""
    return {**state, **{k: v for k, v in defaults.items() if k not in state}}


def _ensemble_v1(state: dict) -> dict:
    """An ensemble's state (IEM, old IEM, the IEM held by IEM+phys): learners without the
    velocity precision have none; without slot generations every slot is at 0; without a
    reservoir it keeps none; without the counters none retired, and with a budget none
    promoted and none on probation (every bag permanent)."""
    learners = [_filled(lr, {"dq_precision": None}) for lr in state["learners"]]
    defaults = {"gen": [0] * len(learners), "kept": None, "retired": 0}
    if state["params"].get("budget_bags") is not None:
        defaults.update(on_probation=[], promoted=0)
    return {**_filled(state, defaults), "learners": learners}


def _regression_v1(state: dict) -> dict:
    """A regression's state (LS, the one IEM+phys holds): a filter saved with ``prev_dq``
    and no ``previous`` starts again at the next sample; the block being averaged, the last
    input and the filter's own input, output and previous output are empty if absent."""
    out = _filled(state, {"input": None, "output": None, "previous": None,
                          "block": [_zeros(21), 0], "last": None})
    if out.pop("prev_dq", None) is not None and out["previous"] is None:
        out.update(filter=None, input=None, output=None)
    return out


def _physics_v1(state: dict) -> dict:
    """An IEM+phys state, its ensemble and regression included (see :func:`fill_version_1`
    for the rules)."""
    params = state["params"]
    out = _filled(state, {"calib_gen": [], "initial": None,
                          "calib_bins": {"sq": _zeros(6, 10), "n": [0] * 6}})
    out["ensemble"] = _ensemble_v1(state["ensemble"])
    out["regression"] = _regression_v1(state["regression"])
    if "bag_counts" not in out:  # the summed covariances, not yet per bag
        out["bag_counts"], out["sum_c_base"] = [], out.pop("sum_c")
    detector = dict(out["detector"])
    detector.setdefault("level", 7.0)
    detector.setdefault("n", 10 if params.get("torque_noise") is None else 0)
    detector.setdefault("level_model", detector["level"])
    out["detector"] = detector
    if params.get("torque_noise") is not None and "offsets" not in out:
        out["offsets"] = [_zeros(10, 7), _zeros(7, 7), _zeros(7)]
        if out["m"]:  # its equations without their offset sums cannot be marginalised
            out.update(info=_zeros(10, 10), eta=_zeros(10), m=0)
    post = out["post"]
    if post is not None and not isinstance(post, dict):
        mean, cov, precision, inflation = post[:4]
        out["post"] = {"mean": mean, "cov": cov, "precision": precision,
                       "inflation": inflation, "equations": out["m"]}
    out.setdefault("data_shown", out["m"] > 0)
    return out


def fill_version_1(kind: str, state: dict, records: Mapping | None = None) -> dict:
    """Version 1 -> 2: a version-1 state of any age in the full version-1 layout.

    What a version-1 file may lack, and what it then meant:

    - IEM, old IEM, and the IEM that IEM+phys holds: a learner's ``dq_precision`` (None: no
      velocity score), ``gen`` (every slot at generation 0), ``kept`` (no reservoir),
      ``retired`` (0), and with a budget ``promoted`` (0) and ``on_probation`` (none: every
      bag permanent).
    - BEM: a learner's ``dq_precision``.
    - LS, and the regression IEM+phys holds: ``input``, ``output``, ``previous``, ``last``
      (None), ``block`` (empty); a filter saved with ``prev_dq`` and without ``previous``
      starts again (``filter`` None).
    - IEM+phys: ``calib_gen`` (empty), ``calib_bins`` (an empty table of the 6 mass bins:
      factors 1), ``bag_counts`` (none; ``sum_c`` becomes ``sum_c_base``), the detector's
      ``level`` (7, the nominal), ``n`` (10 equations, learnt already; 0 with a torque
      noise, whose detector has no level) and ``level_model`` (its ``level``), the window's
      ``offsets`` when a torque noise carries them (a window of equations without them
      starts again), ``post`` as the list ``[mean, cov, precision, inflation]`` (it holds
      the window's equations), ``data_shown`` (the window holds equations) and
      ``initial`` (None).
    """
    if kind in ("IEM", "old_IEM"):
        return _ensemble_v1(state)
    if kind == "BEM":
        return {**state, "learners": [_filled(lr, {"dq_precision": None})
                                      for lr in state["learners"]]}
    if kind == "LS":
        return _regression_v1(state)
    if kind == "IEM+phys":
        return _physics_v1(state)
    return state


# -- 2 -> 3 ------------------------------------------------------------------------------
def equations_per_point(kind: str, state: dict, records: Mapping | None = None) -> dict:
    """Version 2 -> 3: block points instead of frames (see the module docstring). Params
    without them had the version-2 defaults: 1000 Hz, and 10 frames per equation for
    IEM+phys."""
    if kind not in ("IEM+phys", "LS"):
        return state
    params = state["params"]
    rate = float(params.get("rate_hz", 1000.0))
    if kind == "IEM+phys":
        every = int(params.get("update_every", 10))
        # the refresh schedule is saved from now on; version-2 code loaded a file as not
        # stale, nothing counted, every group undetermined until its next refresh
        state = {**state, "stale": False, "since_refresh": 0,
                 "undetermined": ["mass", "com", "inertia"]}
        if every <= 1:
            return {**state, "params": {**params, "point_frames": 1}}
        return {**state, "params": {**params, "rate_hz": rate / every, "update_every": 1,
                                    "point_frames": every}}
    if kind == "LS":
        frames = 10  # the block of the service's default (iem.types.DEFAULT_BLOCK_FRAMES)
        return {**state, "params": {**params, "rate_hz": rate / frames,
                                    "point_frames": frames},
                # a filter of frames: it starts again at the first point
                "filter": None, "input": None, "output": None, "previous": None,
                "block": [[0.0] * 21, 0], "last": None}
    return state


# -- 3 -> 4 ------------------------------------------------------------------------------
NAMED_END_EFFECTORS = ("franka_hand", "none")
"""End effectors a version-3 ``nominal_dynamics`` spec named by name (any other was a path)."""
BY_CONTENT = ("arm_dynamics", "reversed_velocities")
"""The version-3 factories whose ``@ARG`` was an arm file's path."""


def content_references(kind: str, state: dict, records: Mapping | None = None) -> dict:
    """Version 3 -> 4: every factory spec that names a file by path names its arm by content
    (see the module docstring); ``records["arm"]`` is the arm the file records.

    Raises:
        InvalidInputError: a spec names a file by path, and the file records no arm.
    """
    arm = (records or {}).get("arm")

    def by_content(key: str, spec: str) -> str:
        target, at, arg = spec.partition("@")
        function = current_path(target).partition(":")[2]
        if not at or (function == "nominal_dynamics" and arg in NAMED_END_EFFECTORS):
            return spec
        if function not in (*BY_CONTENT, "nominal_dynamics"):
            return spec
        if arm is None:
            raise InvalidInputError(f"{key} {spec!r} names a file by its path and the model "
                                    f"file records no arm to name it by content; make the "
                                    f"model again with 'iem train --arm ARM --out MODEL'")
        ref = f"arm:{int(arm['crc32']) & 0xFFFFFFFF:08x}"
        if function == "nominal_dynamics":  # the nominal arm carrying a tool: that arm
            return f"sim.arm:arm_dynamics@{ref}"
        return f"{target}@{ref}"

    def walk(m: dict) -> dict:
        out = None
        for key, value in m.items():
            new = value
            if isinstance(value, dict):
                new = walk(value)
            elif key in SPEC_KEYS and isinstance(value, str):
                new = by_content(key, value)
            if new is not value:
                out = dict(m) if out is None else out
                out[key] = new
        return m if out is None else out

    return walk(state)


# -- 4 -> 5 ------------------------------------------------------------------------------
def learner_named(kind: str, state: dict, records: Mapping | None = None) -> dict:
    """Version 4 -> 5: an ensemble's hyper-parameters name how its learners are trained
    (``learner``); every version-4 ensemble trained them by SGD (``"sgd"``): the IEM's and
    old IEM's, and the one IEM+phys holds (whose params keep only what was given: ``learner``
    is added to its ``ensemble``)."""
    if kind in ("IEM", "old_IEM"):
        return {**state, "params": {**state["params"], "learner": "sgd"}}
    if kind == "IEM+phys":
        params = state["params"]
        ens = state["ensemble"]
        given = {**(params.get("ensemble") or {}), "learner": "sgd"}
        return {**state, "params": {**params, "ensemble": given},
                "ensemble": {**ens, "params": {**ens["params"], "learner": "sgd"}}}
    return state


# -- 5 -> 6 ------------------------------------------------------------------------------
def candidate_kept(kind: str, state: dict, records: Mapping | None = None) -> dict:
    """Version 5 -> 6: an IEM+phys state holds its candidate posterior (``candidate``,
    :class:`iem.physics.candidate.Candidate`); a version-5 file kept none."""
    if kind == "IEM+phys":
        return {**state, "candidate": None}
    return state


STEPS: dict[int, Step] = {1: fill_version_1, 2: equations_per_point, 3: content_references,
                          4: learner_named, 5: candidate_kept}
"""``version -> step`` to ``version + 1``."""

VERSION = 1 + len(STEPS)
"""The schema version files are written at: the last step's."""


def migrate(kind: str, state: dict, version: int, records: Mapping | None = None) -> dict:
    """The state of a file of ``version`` (1 to :data:`VERSION`) at :data:`VERSION`: every
    step from ``version`` on, in order, each given the file's ``records`` (``{"arm": ...}``);
    ``state`` is left as it was.

    Raises:
        InvalidInputError: ``version`` is not one of 1 to :data:`VERSION`.
    """
    if type(version) is not int or not 1 <= version <= VERSION:
        raise InvalidInputError(f"schema version {version!r} is not one of 1 to {VERSION}")
    for v in range(version, VERSION):
        state = STEPS[v](kind, state, records)
    return state
