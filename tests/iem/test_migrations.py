"""Model-file schema versions: every old file loads to the model it held, at the newest
version; each step on its own; the module-path aliases.

``data/v1_*.iem`` are files the version-1 code wrote (an IEM+phys at 1 kHz with blocks of
10 samples, an LS), and ``data/v1_expected.json`` what each predicted then at a sample
(``x``, ``flange``), on the machine that wrote them: the loaded model must predict the same,
to :data:`SAME_ARITHMETIC`.
"""

from __future__ import annotations

import copy
import importlib
import importlib.util
import json
import zlib
from pathlib import Path

import msgpack
import numpy as np
import pytest

from iem import migrations
from iem.baselines.least_squares import RecursiveLeastSquares
from iem.errors import InvalidInputError, ModelFileError
from iem.migrations import (
    STEPS,
    VERSION,
    candidate_kept,
    current_path,
    equations_per_point,
    fill_version_1,
    learner_named,
    migrate,
    with_current_paths,
)
from iem.model_kinds import MODELS, new_model
from iem.persistence import dumps, load_model, loads
from iem.physics.consistency import is_consistent
from iem.physics.model import PhysicsInformedEnsemble
from sim.arm import NOMINAL_DYNAMICS
from tests.iem.test_consistency import _clipped_distance

DATA = Path(__file__).parent / "data"
FIXTURES = sorted(DATA.glob("v*_*.iem"))
EXPECTED = json.loads((DATA / "v1_expected.json").read_text())


def _head(path: Path) -> tuple[dict, dict]:
    """The file's header and its unpacked state."""
    head = msgpack.unpackb(path.read_bytes(), raw=False)
    return head, msgpack.unpackb(head["state"], raw=False, strict_map_key=False)


def _file(kind: str, state: dict, version: int) -> bytes:
    packed = msgpack.packb(state, use_bin_type=True)
    return msgpack.packb({"schema": "iem-payload-model", "version": version, "kind": kind,
                          "crc32": zlib.crc32(packed), "state": packed}, use_bin_type=True)


SAME_ARITHMETIC = 1e-10
"""Relative tolerance of a prediction against ``v1_expected.json``: the same arithmetic on
the same state, up to the last bits, which depend on the machine's BLAS kernels (OpenBLAS's
SkylakeX, Haswell and Sandybridge kernels on one CPU differ by up to 6e-14 relative on
these fixtures); a state that a migration changed predicts otherwise by far more."""


PROJECTION_RTOL = 1e-6
"""The consistency projection's accuracy (:func:`iem.physics.consistency.project`'s
``rtol``): the version-1 code's projection and this code's are different algorithms, each
within ``sqrt(2 rtol dist0)`` of the same optimum in the posterior's metric (``dist0`` the
clipped point's distance), so their projected phi agree to twice that, not to the bit."""


def assert_predicts_as_version_1(model, expected: dict) -> None:
    """``model`` predicts at ``expected``'s sample what the version-1 code predicted: its
    posterior to the last bits; for IEM+phys, whose mean is projected onto consistent
    parameters, its phi to the projection's accuracy (:data:`PROJECTION_RTOL`)."""
    est = model.predict_one(np.array(expected["x"]), np.array(expected["flange"]))
    np.testing.assert_allclose(est.std, expected["std"], rtol=SAME_ARITHMETIC, atol=0.0)
    if not isinstance(model, PhysicsInformedEnsemble):
        np.testing.assert_allclose(est.phi, expected["phi"], rtol=SAME_ARITHMETIC, atol=0.0)
        return
    post = model._posterior()
    assert not is_consistent(post.mean, post.eps)  # the fixture's mean is projected
    dist0 = _clipped_distance(post.mean, post.precision, post.eps)
    d = est.phi - np.array(expected["phi"])
    assert np.sqrt(d @ post.precision @ d) <= 2.0 * np.sqrt(2.0 * PROJECTION_RTOL * dist0)


PHYS_HEAD, PHYS_V1 = _head(DATA / "v1_iem_phys.iem")
LS_HEAD, LS_V1 = _head(DATA / "v1_ls.iem")


def _canonical(obj):
    if isinstance(obj, dict):
        return sorted((k, _canonical(v)) for k, v in obj.items())
    if isinstance(obj, list):
        return [_canonical(v) for v in obj]
    return obj


def _same_state(a: dict, b: dict) -> bool:
    """Equal states, NaN included and key order aside (their canonical msgpack bytes)."""
    return (msgpack.packb(_canonical(a), use_bin_type=True)
            == msgpack.packb(_canonical(b), use_bin_type=True))


# -- old files load to the same model, at the newest version ---------------------------------
def test_the_fixtures_are_version_1_files():
    assert [p.name for p in FIXTURES] == ["v1_iem_phys.iem", "v1_ls.iem"]
    assert (PHYS_HEAD["version"], PHYS_HEAD["kind"]) == (1, "IEM+phys")
    assert (LS_HEAD["version"], LS_HEAD["kind"]) == (1, "LS")
    assert PHYS_V1["params"]["rate_hz"] == 1000.0 and PHYS_V1["params"]["update_every"] == 10


@pytest.mark.parametrize("path", FIXTURES, ids=lambda p: p.stem)
def test_an_old_file_loads_to_the_model_it_held_and_is_saved_at_the_newest_version(path):
    model = load_model(path)
    head, state = _head(path)
    newest = with_current_paths(migrate(head["kind"], state, 1))  # the moved factory names
    assert _same_state(model.to_state(), newest)
    saved = dumps(model)
    assert_predicts_as_version_1(model, EXPECTED[path.stem.partition("_")[2]])
    assert msgpack.unpackb(saved, raw=False)["version"] == VERSION
    again = loads(saved)
    assert _same_state(again.to_state(), newest)
    assert again.dynamics == NOMINAL_DYNAMICS  # the spec it was given, not the caller's


def test_the_1khz_physics_file_takes_100hz_points_after_loading():
    model = load_model(DATA / "v1_iem_phys.iem")
    assert (model.rate_hz, model.update_every, model.point_frames) == (100.0, 1, 10)
    moved = ("rate_hz", "update_every", "point_frames", "ensemble")
    params = {k: v for k, v in model.params().items() if k not in moved}
    assert params == {k: v for k, v in with_current_paths(PHYS_V1["params"]).items()
                      if k not in moved}
    # its ensemble learnt by SGD, and says so now (the default is the fast learner)
    assert model.params()["ensemble"] == {**PHYS_V1["params"]["ensemble"], "learner": "sgd"}
    assert model._ens.learner_kind == "sgd"


def test_the_oldest_version_1_state_loads_as_its_branches_read_it():
    """Every field a version-1 file may lack, absent at once: the model loads and predicts as
    the full file's, but for what the fill says (no reservoir, an empty calibration table)."""
    state = copy.deepcopy(PHYS_V1)
    for key in ("calib_gen", "calib_bins", "initial", "data_shown"):
        del state[key]
    state["sum_c"] = state.pop("sum_c_base")
    del state["bag_counts"]
    post = state["post"]
    state["post"] = [post["mean"], post["cov"], post["precision"], post["inflation"]]
    for key in ("level", "n", "level_model"):
        del state["detector"][key]
    for key in ("input", "output", "previous", "block", "last"):
        del state["regression"][key]
    for key in ("gen", "kept", "retired"):
        del state["ensemble"][key]
    for learner in state["ensemble"]["learners"]:
        del learner["dq_precision"]
    old = loads(_file("IEM+phys", state, 1))
    full = load_model(DATA / "v1_iem_phys.iem")
    assert old.n_bags == full.n_bags and old.changes == full.changes
    assert old.ensemble_prior.calib_gen == []
    assert old.ensemble_model.learner(0).dq_precision is None
    x, f = np.array(EXPECTED["iem_phys"]["x"]), np.array(EXPECTED["iem_phys"]["flange"])
    assert np.isfinite(old.predict_one(x, f).phi).all()


def test_a_file_newer_than_the_code_is_refused_naming_both_versions(tmp_path):
    path = tmp_path / "new.iem"
    path.write_bytes(_file("LS", LS_V1, VERSION + 1))
    with pytest.raises(ModelFileError, match=rf"{path} has schema version {VERSION + 1}, newer "
                                             rf"than this build's {VERSION}"):
        load_model(path)


def test_a_state_no_step_can_bring_up_is_a_model_file_error():
    state = copy.deepcopy(LS_V1)
    del state["count"]
    broken = {k: v for k, v in PHYS_V1.items() if k != "ensemble"}
    with pytest.raises(ModelFileError, match=r"does not describe a valid LS"):
        loads(_file("LS", state, 1))
    with pytest.raises(ModelFileError, match=r"state of version 1 cannot be brought to version "
                                             rf"{VERSION}: KeyError"):
        loads(_file("IEM+phys", broken, 1))


# -- the steps, each on its own -----------------------------------------------------------
def test_the_steps_run_in_order_from_the_files_version():
    assert sorted(STEPS) == list(range(1, VERSION))
    assert migrate("IEM+phys", PHYS_V1, VERSION) is PHYS_V1
    newest = migrate("IEM+phys", PHYS_V1, 1)
    assert newest == candidate_kept("IEM+phys", learner_named("IEM+phys", equations_per_point(
        "IEM+phys", fill_version_1("IEM+phys", PHYS_V1))))  # 3 -> 4 has nothing to do here
    for bad in (0, VERSION + 1, "1", 1.0, True):
        with pytest.raises(InvalidInputError, match=rf"not one of 1 to {VERSION}"):
            migrate("LS", LS_V1, bad)


@pytest.mark.parametrize("step", list(STEPS.values()), ids=lambda s: s.__name__)
@pytest.mark.parametrize(("kind", "state"), [("IEM+phys", PHYS_V1), ("LS", LS_V1),
                                             ("arm", {"link_params": [1.0]})])
def test_a_step_leaves_its_argument_as_it_was(step, kind, state):
    before = copy.deepcopy(state)
    step(kind, state)
    assert state == before


def test_learner_named_says_every_version_4_ensemble_learnt_by_sgd():
    phys = learner_named("IEM+phys", PHYS_V1)
    assert phys["params"]["ensemble"] == {**PHYS_V1["params"]["ensemble"], "learner": "sgd"}
    assert phys["ensemble"]["params"] == {**PHYS_V1["ensemble"]["params"], "learner": "sgd"}
    ens = PHYS_V1["ensemble"]
    for kind in ("IEM", "old_IEM"):
        assert learner_named(kind, ens)["params"] == {**ens["params"], "learner": "sgd"}
    assert learner_named("LS", LS_V1) is LS_V1


def test_candidate_kept_says_a_version_5_iem_phys_kept_no_candidate():
    phys = candidate_kept("IEM+phys", PHYS_V1)
    assert phys == {**PHYS_V1, "candidate": None}
    for kind, state in (("IEM", PHYS_V1["ensemble"]), ("LS", LS_V1)):
        assert candidate_kept(kind, state) is state


def test_fill_version_1_leaves_a_full_version_1_state_as_it_is():
    assert fill_version_1("IEM+phys", PHYS_V1) == PHYS_V1
    assert fill_version_1("LS", LS_V1) == LS_V1
    assert fill_version_1("arm", {"report": None}) == {"report": None}


def test_fill_version_1_ensemble_fields():
    ens = copy.deepcopy(PHYS_V1["ensemble"])
    for key in ("gen", "kept", "retired"):
        del ens[key]
    del ens["learners"][0]["dq_precision"]
    out = fill_version_1("IEM", ens)
    n = len(ens["learners"])
    assert out["gen"] == [0] * n and out["kept"] is None and out["retired"] == 0
    assert "promoted" not in out and "on_probation" not in out  # no budget
    assert out["learners"][0]["dq_precision"] is None
    assert fill_version_1("old_IEM", ens) == out
    ens["params"]["budget_bags"] = 40
    budgeted = fill_version_1("IEM", ens)
    assert (budgeted["retired"], budgeted["promoted"], budgeted["on_probation"]) == (0, 0, [])
    bem = fill_version_1("BEM", {"params": {}, "learners": [{"a": [1.0]}], "trees": []})
    assert bem["learners"] == [{"a": [1.0], "dq_precision": None}]


def test_fill_version_1_regression_fields():
    reg = {"count": 5, "filter": [[1.0] * 21, [2.0] * 21], "input": [0.5] * 21,
           "output": [0.5] * 21, "prev_dq": [0.0] * 7}
    out = fill_version_1("LS", {**reg, "params": {}})
    # saved with prev_dq and no previous output: the filter starts again
    assert out["filter"] is None and out["input"] is None and out["output"] is None
    assert "prev_dq" not in out and out["previous"] is None and out["last"] is None
    assert out["block"] == [[0.0] * 21, 0] and out["count"] == 5
    kept = fill_version_1("LS", {**reg, "previous": [0.4] * 21, "params": {}})
    assert kept["filter"] == reg["filter"] and kept["previous"] == [0.4] * 21


def test_fill_version_1_physics_fields():
    state = copy.deepcopy(PHYS_V1)
    for key in ("calib_gen", "calib_bins", "initial", "data_shown", "bag_counts"):
        del state[key]
    state["sum_c"] = state.pop("sum_c_base")
    post = state["post"]
    state["post"] = [post["mean"], post["cov"], post["precision"], post["inflation"]]
    for key in ("level", "n", "level_model"):
        del state["detector"][key]
    out = fill_version_1("IEM+phys", state)
    assert out["calib_gen"] == [] and out["initial"] is None
    assert out["calib_bins"] == {"sq": [[0.0] * 10] * 6, "n": [0] * 6}
    assert out["bag_counts"] == [] and out["sum_c_base"] == PHYS_V1["sum_c_base"]
    assert "sum_c" not in out
    assert out["post"] == {**post, "equations": PHYS_V1["m"]}
    assert out["data_shown"] is (PHYS_V1["m"] > 0)
    assert out["detector"] == {**PHYS_V1["detector"], "level": 7.0, "n": 10,
                               "level_model": 7.0}


def test_fill_version_1_a_window_without_offset_sums_starts_again():
    state = copy.deepcopy(PHYS_V1)
    state["params"]["torque_noise"] = {"offset_std": [0.1] * 7}
    del state["detector"]["n"]
    out = fill_version_1("IEM+phys", state)
    assert out["offsets"] == [[[0.0] * 7] * 10, [[0.0] * 7] * 7, [0.0] * 7]
    assert out["m"] == 0 and out["info"] == [[0.0] * 10] * 10 and out["eta"] == [0.0] * 10
    assert out["post"]["equations"] == PHYS_V1["post"]["equations"]  # a dict already
    assert out["detector"]["n"] == 0  # a detector without a level
    empty = fill_version_1("IEM+phys", {**state, "m": 0, "info": [[1.0] * 10] * 10})
    assert empty["info"] == [[1.0] * 10] * 10 and empty["m"] == 0


@pytest.mark.parametrize(("rate", "every", "after"), [
    (1000.0, 10, (100.0, 1)), (2000.0, 20, (100.0, 1)), (500.0, 5, (100.0, 1)),
    (100.0, 1, (100.0, 1)), (1000.0, 1, (1000.0, 1))])
def test_equations_per_point(rate, every, after):
    noise = {"rate_hz": 100.0, "cutoff_hz": 4.0}
    state = {"params": {"rate_hz": rate, "update_every": every, "torque_noise": noise,
                        "cutoff_hz": 4.0}, "regression": {"count": 3}, "holdoff": 7}
    out = equations_per_point("IEM+phys", state)
    assert (out["params"]["rate_hz"], out["params"]["update_every"]) == after
    assert out["params"]["point_frames"] == every  # the same noise per equation
    assert out["params"]["torque_noise"] == noise and out["params"]["cutoff_hz"] == 4.0
    assert {k: v for k, v in out.items() if k != "params"} == {
        **{k: v for k, v in state.items() if k != "params"},
        "stale": False, "since_refresh": 0, "undetermined": ["mass", "com", "inertia"]}


def test_equations_per_point_reads_absent_params_as_the_version_2_defaults():
    out = equations_per_point("IEM+phys", {"params": {}})
    assert (out["params"]["rate_hz"], out["params"]["update_every"]) == (100.0, 1)


def test_equations_per_point_gives_ls_the_default_block_and_restarts_its_filter():
    ls = {"params": {"rate_hz": 1000.0}, "filter": [[0.5] * 21] * 2, "last": [1.0] * 21}
    out = equations_per_point("LS", ls)
    assert out["params"] == {"rate_hz": 100.0, "point_frames": 10}
    assert out["filter"] is None and out["last"] is None


def test_equations_per_point_leaves_other_kinds():
    iem = {"params": {"seed": 0}}
    assert equations_per_point("IEM", iem) is iem


# -- module paths that moved ----------------------------------------------------------------
def test_the_alias_table_names_importable_paths():
    for new in migrations.ALIASES.values():
        module, _, name = current_path(new).partition(":")
        loaded = importlib.import_module(module)
        assert not name or hasattr(loaded, name), new


def test_current_path_follows_rows_keeps_the_argument_and_refuses_a_cycle(monkeypatch):
    monkeypatch.setattr(migrations, "ALIASES", {
        "old.a": "mid.a", "mid.a": "new.a", "old.b:f": "new.b:g", "x": "y", "y": "x"})
    assert current_path("old.a:f@/arm.msgpack") == "new.a:f@/arm.msgpack"
    assert current_path("old.b:f") == "new.b:g" and current_path("old.b:h") == "old.b:h"
    assert current_path("sim.arm:arm_dynamics") == "sim.arm:arm_dynamics"
    with pytest.raises(InvalidInputError, match="cycle"):
        current_path("x:f")


def test_a_file_naming_a_moved_module_loads_and_is_saved_with_its_new_path(monkeypatch):
    state = copy.deepcopy(PHYS_V1)
    state["params"]["dynamics"] = "sim.arm_before:arm_dynamics"
    state["params"]["ensemble"]["reversal"] = "sim.coverage_before:reversed_velocities"
    state["ensemble"]["params"]["reversal"] = "sim.coverage_before:reversed_velocities"
    state["ensemble"]["params"]["coverage"] = "sim.coverage_before:other_velocities"
    with pytest.raises(ModelFileError, match=r"sim\.coverage_before"):
        loads(_file("IEM+phys", state, 1))
    monkeypatch.setattr(migrations, "ALIASES", {"sim.arm_before": "sim.arm",
                                                "sim.coverage_before": "sim.coverage"})
    model = loads(_file("IEM+phys", state, 1))
    assert model.dynamics == NOMINAL_DYNAMICS
    assert model.params()["ensemble"]["reversal"] == "sim.coverage:reversed_velocities"
    assert model.ensemble_model.params()["coverage"] == "sim.coverage:other_velocities"
    assert b"_before" not in dumps(model)
    assert with_current_paths(state) is not state  # the argument is left as it was
    assert state["params"]["dynamics"] == "sim.arm_before:arm_dynamics"


def test_a_registered_class_at_a_moved_path_loads(monkeypatch):
    data = (DATA / "v1_ls.iem").read_bytes()
    registry = {"LS": "iem.ls_before:RecursiveLeastSquares"}
    with pytest.raises(ModelFileError, match="cannot be imported"):
        loads(data, registry=registry)
    monkeypatch.setattr(migrations, "ALIASES",
                        {**migrations.ALIASES, "iem.ls_before": "iem.baselines.least_squares"})
    assert isinstance(loads(data, registry=registry), RecursiveLeastSquares)


# -- iem's modules into sub-packages (issue 29 point 4) ---------------------------------------
OLD_MODELS = {"IEM": "iem.ensemble:IncrementalEnsemble", "old_IEM": "iem.old_iem:InPlaceEnsemble",
              "BEM": "iem.bem:BatchEnsemble", "LS": "iem.least_squares:RecursiveLeastSquares",
              "IEM+phys": "iem.physics:PhysicsInformedEnsemble"}
"""The estimators' classes as :data:`iem.model_kinds.MODELS` named them before iem/ became
sub-packages."""


def test_each_old_class_path_leads_to_the_class_models_names_now():
    assert sorted(OLD_MODELS) == sorted(MODELS)
    for kind, old in OLD_MODELS.items():
        assert current_path(old) == MODELS[kind], kind


@pytest.mark.parametrize("old", ["iem.old_iem", "iem.bem", "iem.tree", "iem.least_squares",
                                 "iem.filters", "iem.worker", "iem.regression",
                                 "iem.torque_noise"])
def test_no_module_is_left_at_an_old_path(old):
    """One home per thing: a moved module is found only through the alias table."""
    assert importlib.util.find_spec(old) is None


@pytest.mark.parametrize("path", FIXTURES, ids=lambda p: p.stem)
def test_the_fixtures_load_through_a_registry_naming_the_old_paths(path):
    head, _ = _head(path)
    model = loads(path.read_bytes(), registry=OLD_MODELS)
    module, _, name = MODELS[head["kind"]].partition(":")
    assert type(model) is getattr(importlib.import_module(module), name)
    assert _same_state(model.to_state(), load_model(path).to_state())
    assert_predicts_as_version_1(model, EXPECTED[path.stem.partition("_")[2]])


@pytest.mark.parametrize("kind", sorted(OLD_MODELS))
def test_a_file_of_each_kind_loads_through_its_old_class_path(kind):
    params = {"dynamics": NOMINAL_DYNAMICS} if kind in ("LS", "IEM+phys") else {}
    data = dumps(new_model(kind, **params))
    model = loads(data, registry=OLD_MODELS)
    module, _, name = MODELS[kind].partition(":")
    assert type(model) is getattr(importlib.import_module(module), name)
    assert dumps(model) == data
