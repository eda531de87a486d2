"""A model file holds data, never code: its factory specs are names in a fixed table
(:mod:`iem.factories`), and the arm it runs on is referenced by content and given at run
time, never by path.

The forged files are real model files whose state was edited and whose CRC was computed
again by the rule :mod:`iem.persistence` documents (here, not by its code), so that only the
spec is wrong.
"""

from __future__ import annotations

import shutil
import sys
import zlib

import msgpack
import numpy as np
import pytest

from deploy.cli import main
from iem import factories
from iem.errors import InvalidInputError, ModelFileError
from iem.model_kinds import new_model
from iem.persistence import VERSION, dumps, load_model, loads
from sim.arm import NOMINAL_DYNAMICS, ArmParams, arm_record, arm_spec, load_arm, save_arm
from sim.end_effector import NAMED
from sim.family import PAYLOAD_DIR
from sim.plant import RealityGap

REVERSAL = "sim.coverage:reversed_velocities"


def rewritten(data: bytes, edit, version: int | None = None) -> bytes:
    """The model file ``data`` with ``edit(state)`` applied (and ``version`` set), its CRC
    computed again: the state's, over the arm record, the family and the version."""
    head = msgpack.unpackb(data, raw=False)
    state = msgpack.unpackb(head["state"], raw=False, strict_map_key=False)
    edit(state)
    head["state"] = msgpack.packb(state, use_bin_type=True)
    if version is not None:
        head["version"] = version
    crc = zlib.crc32(head["state"])
    if "arm" in head:
        crc = zlib.crc32(msgpack.packb(head["arm"], use_bin_type=True), crc)
    if "family" in head:
        crc = zlib.crc32(head["family"].encode("utf-8"), crc)
    head["crc32"] = zlib.crc32(msgpack.packb(head["version"]), crc)
    return msgpack.packb(head, use_bin_type=True)


def setter(*keys: str, value):
    def edit(state):
        for key in keys[:-1]:
            state = state[key]
        state[keys[-1]] = value
    return edit


@pytest.fixture
def evil(tmp_path, monkeypatch):
    """``(specs, witnesses)``: specs that would run code if a loader imported or called
    them (a shell command; a module on the path that writes a file when imported), and the
    files that would then exist."""
    ran, imported = tmp_path / "ran", tmp_path / "imported"
    (tmp_path / "evil_factory.py").write_text(
        f"from pathlib import Path\nPath({str(imported)!r}).touch()\ndef make(*a):\n"
        f"    return None\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    yield [f"os:system@touch {ran}", "evil_factory:make"], (ran, imported)
    assert "evil_factory" not in sys.modules


def _physics_file() -> bytes:
    return dumps(new_model("IEM+phys", dynamics=NOMINAL_DYNAMICS, ensemble={"reversal": REVERSAL}))


def test_the_rewrite_alone_leaves_a_loadable_file():
    """The forgery's CRC rule is the file's: an edit that changes nothing still loads."""
    data = _physics_file()
    assert loads(rewritten(data, lambda state: None)).dynamics == NOMINAL_DYNAMICS


@pytest.mark.parametrize(("kind", "keys"), [
    ("IEM+phys", ("params", "dynamics")),
    ("IEM+phys", ("params", "ensemble", "reversal")),
    ("IEM+phys", ("ensemble", "params", "reversal")),
    ("IEM+phys", ("ensemble", "params", "coverage")),
    ("IEM", ("params", "reversal")),
    ("IEM", ("params", "coverage")),
    ("LS", ("params", "dynamics"))])
def test_a_spec_outside_the_table_is_refused_naming_it_and_nothing_runs(kind, keys, evil,
                                                                       tmp_path):
    specs, witnesses = evil
    params = {"IEM+phys": {"dynamics": NOMINAL_DYNAMICS, "ensemble": {"reversal": REVERSAL}},
              "IEM": {"reversal": REVERSAL}, "LS": {"dynamics": NOMINAL_DYNAMICS}}[kind]
    data = dumps(new_model(kind, **params))
    for spec in specs:
        path = tmp_path / "forged.msgpack"
        path.write_bytes(rewritten(data, setter(*keys, value=spec)))
        with pytest.raises(ModelFileError) as err:
            load_model(path)
        message = str(err.value)
        assert str(path) in message and repr(spec) in message
        assert "valid are" in message and "sim.arm:arm_dynamics" in message
        for witness in witnesses:
            assert not witness.exists()


def test_iem_replay_of_a_forged_model_exits_2_naming_the_spec(evil, tmp_path, capsys):
    specs, witnesses = evil
    recording = tmp_path / "rec.csv"
    header = ["t", *(f"{s}{i}" for s in ("q", "dq", "tau") for i in range(1, 8))]
    rows = [",".join(map(str, [0.001 * k, *np.zeros(21)])) for k in range(50)]
    recording.write_text("\n".join([",".join(header), *rows]) + "\n")
    data = _physics_file()
    for keys in (("params", "dynamics"), ("params", "ensemble", "reversal"),
                 ("ensemble", "params", "coverage")):
        for spec in specs:
            model = tmp_path / "forged.msgpack"
            model.write_bytes(rewritten(data, setter(*keys, value=spec)))
            capsys.readouterr()
            assert main(["replay", str(recording), "--model", str(model), "--no-status"]) == 2
            err = capsys.readouterr().err
            assert err.startswith("iem: error: ") and repr(spec) in err, err
            for witness in witnesses:
                assert not witness.exists()


def test_the_table_names_only_sim_factories_that_exist_and_the_named_end_effectors():
    import importlib

    for key, row in factories.FACTORIES.items():
        module, _, name = row.target.partition(":")
        assert callable(getattr(importlib.import_module(module), name)), key
    assert factories.FACTORIES["sim.arm:nominal_dynamics"].names == NAMED


@pytest.mark.parametrize("spec", [
    "sim.arm:arm_dynamics@/abs/arm.msgpack", "sim.arm:nominal_dynamics@/abs/tool.toml",
    "sim.coverage:reversed_velocities@arm.msgpack", "sim.robot:panda_dynamics@none",
    "sim.arm:arm_dynamics@arm:1234", "sim.arm:arm_dynamics@tool:0123abcd",
    "sim.arm:arm_dynamics@", "sim.robot:panda_dynamics "])
def test_a_spec_with_a_path_or_an_argument_its_factory_does_not_take_is_refused(spec):
    with pytest.raises(InvalidInputError, match=r"valid are "):
        factories.parse(spec, "dynamics")


# -- the arm: by content, given at run time ---------------------------------------------------
@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """``(model file, arm file)``: IEM+phys trained by ``iem train --arm`` in one directory,
    for an arm whose measured noise names the recording it came from by its path, as
    ``iem calibrate`` writes it (sim.calibration_noise)."""
    from dataclasses import replace

    from iem.physics.torque_noise import NOMINAL_ARM_NOISE

    d = tmp_path_factory.mktemp("trained")
    noise = {**NOMINAL_ARM_NOISE.to_dict(),
             "source": f"5-fold cross-validation on {d / 'bare.blf'}"}
    save_arm(replace(RealityGap(seed=3).realise(), noise=noise), d / "arm.msgpack")
    assert main(["train", "--kind", "IEM+phys", "--arm", str(d / "arm.msgpack"),
                 "--out", str(d / "model.msgpack")]) == 0
    return d / "model.msgpack", d / "arm.msgpack"


def _strings(obj) -> list[str]:
    if isinstance(obj, dict):
        return [s for k, v in obj.items() for s in (*_strings(k), *_strings(v))]
    if isinstance(obj, list):
        return [s for v in obj for s in _strings(v)]
    return [obj] if isinstance(obj, str) else []


def test_a_model_file_names_no_path(trained):
    model_file, arm_file = trained
    data = model_file.read_bytes()
    head = msgpack.unpackb(data, raw=False)
    state = msgpack.unpackb(head["state"], raw=False, strict_map_key=False)
    assert str(arm_file.parent).encode() not in data
    assert not [s for s in _strings(state) + _strings(head["arm"]) if "/" in s or "\\" in s]


def test_a_moved_model_runs_with_its_arm_given_from_elsewhere(trained, tmp_path):
    model_file, arm_file = trained
    (tmp_path / "models").mkdir()
    (tmp_path / "arms").mkdir()
    moved = tmp_path / "models" / "m.msgpack"
    shutil.copy(model_file, moved)
    given = tmp_path / "arms" / "cell-arm.msgpack"
    shutil.copy(arm_file, given)
    arm = load_arm(given)
    model = load_model(moved, resources={"arm": arm})
    assert model.dynamics == f"sim.arm:arm_dynamics@arm:{arm.crc32:08x}"
    assert model.params()["ensemble"]["reversal"] == f"{REVERSAL}@arm:{arm.crc32:08x}"
    # the physics is the given arm's: its torques, friction and offsets included
    from sim.robot import ArmModel

    q, dq, ddq = ArmModel().random_state(np.random.default_rng(0))
    from iem.physics.regression import load_dynamics

    tau = load_dynamics(model.dynamics)(q, dq, ddq)[0]
    np.testing.assert_allclose(tau, ArmModel(arm=arm).rnea(q, dq, ddq), atol=1e-12)

    other_file = tmp_path / "arms" / "other.msgpack"
    save_arm(RealityGap(seed=4).realise(), other_file)
    other = load_arm(other_file)
    with pytest.raises(ModelFileError, match=rf"{moved} was trained for arm file arm\.msgpack "
                                             rf"\(CRC32 {arm.crc32:#010x}.*\) but is run with "
                                             rf"arm file other\.msgpack \(CRC32 "
                                             rf"{other.crc32:#010x}"):
        load_model(moved, resources={"arm": other})
    with pytest.raises(ModelFileError,
                       match=r"arm\.msgpack .* but is run with the default arm model's "
                             r"nominal arm"):
        load_model(moved)


def test_a_model_for_a_tool_on_the_nominal_arm_references_that_arm(tmp_path):
    from deploy.model.training import load_arm_file, make_model

    tool = tmp_path / "tool.toml"
    shutil.copy(PAYLOAD_DIR / "test-3w.toml", tool)
    arm, record = load_arm_file(None, str(tool))
    model = make_model("IEM+phys", end_effector=str(tool))
    model.trained_arm = record
    assert model.dynamics == arm_spec(arm) and str(tmp_path).encode() not in dumps(model)
    (tmp_path / "elsewhere").mkdir()
    shutil.move(tool, tmp_path / "elsewhere" / "tool.toml")
    again, _ = load_arm_file(None, str(tmp_path / "elsewhere" / "tool.toml"))  # same content
    assert loads(dumps(model), resources={"arm": again}).dynamics == model.dynamics
    with pytest.raises(ModelFileError, match=r"trained for the default arm model's nominal arm "
                                             r"with the end effector 'tool:[0-9a-f]{8}' \(no "
                                             r"arm file\) but is run with the default arm "
                                             r"model's nominal arm with the end effector "
                                             r"'franka_hand'"):
        loads(dumps(model))


# -- files of the previous version named the arm by path ---------------------------------------
def _version_3(data: bytes, spec_of) -> bytes:
    """``data`` as the previous version wrote it: every spec that names the arm by content
    names it by ``spec_of(spec)``, version 3."""
    def edit(state):
        for path, spec in factories.specs_in(state):
            *keys, last = path.split(".")
            node = state
            for key in keys:
                node = node[key]
            node[last] = spec_of(spec)
    return rewritten(data, edit, version=3)


def test_a_file_of_the_previous_version_with_an_absolute_arm_path_loads(trained, tmp_path):
    model_file, arm_file = trained
    arm = load_arm(arm_file)
    old = _version_3(model_file.read_bytes(), lambda s: s.replace(
        f"@arm:{arm.crc32:08x}", "@/var/lib/iem/gone/arm.msgpack"))
    assert b"/var/lib/iem/gone/arm.msgpack" in old  # dynamics and reversal by path
    model = loads(old, resources={"arm": arm})
    assert model.dynamics == arm_spec(arm)
    assert model.ensemble_model.reversal == f"{REVERSAL}@arm:{arm.crc32:08x}"
    assert b"/var/lib" not in dumps(model)
    assert msgpack.unpackb(dumps(model), raw=False)["version"] == VERSION
    with pytest.raises(ModelFileError, match="but is run with the default arm model's nominal arm"):
        loads(old)


def test_a_previous_version_file_with_a_tool_path_loads_as_the_nominal_arm_carrying_it(
        tmp_path):
    from deploy.model.training import load_arm_file

    tool = tmp_path / "tool.toml"
    shutil.copy(PAYLOAD_DIR / "test-3w.toml", tool)
    arm, record = load_arm_file(None, str(tool))
    model = new_model("IEM+phys", dynamics="sim.arm:nominal_dynamics@none")
    model.trained_arm = record
    old = _version_3(dumps(model), lambda s: s.replace("@none", f"@{tool}"))
    assert str(tool).encode() in old
    loaded = loads(old, resources={"arm": arm})
    assert loaded.dynamics == f"sim.arm:arm_dynamics@arm:{arm.crc32:08x}"
    assert loaded.trained_arm == record and record == arm_record(ArmParams.nominal(str(tool)))


def test_a_previous_version_file_naming_an_arm_by_path_without_its_record_is_refused():
    data = dumps(new_model("LS", dynamics=NOMINAL_DYNAMICS))
    old = _version_3(data, lambda s: "sim.arm:arm_dynamics@/etc/iem/arm.msgpack")
    with pytest.raises(ModelFileError, match=r"names a file by its path and the model file "
                                             r"records no arm"):
        loads(old)
    named = _version_3(data, lambda s: "sim.arm:nominal_dynamics@none")
    assert loads(named).dynamics == "sim.arm:nominal_dynamics@none"  # a name stays a name


def test_code_may_add_a_factory_a_file_cannot(monkeypatch):
    monkeypatch.setattr(factories, "FACTORIES", dict(factories.FACTORIES))
    data = dumps(new_model("LS", dynamics=NOMINAL_DYNAMICS))
    forged = rewritten(data, setter("params", "dynamics", value="sim.robot:stand_in"))
    with pytest.raises(ModelFileError, match=r"'sim\.robot:stand_in' is not a factory"):
        loads(forged)
    factories.register_factory("sim.robot:stand_in", "sim.arm:arm_dynamics")
    assert loads(forged).dynamics == "sim.robot:stand_in"
    for bad in ("sim.robot.stand_in", "a:b@c", None):
        with pytest.raises(InvalidInputError, match="must be 'module:function'"):
            factories.register_factory(bad)


def test_the_step_rewrites_paths_only_and_leaves_its_argument_as_it_was():
    import copy

    from iem.migrations import content_references

    state = {"params": {"dynamics": "sim.arm:nominal_dynamics@/t/tool.toml",
                        "ensemble": {"reversal": f"{REVERSAL}@/t/arm.msgpack",
                                     "coverage": "sim.coverage:other_velocities"}},
             "ensemble": {"params": {"reversal": REVERSAL}}}
    before = copy.deepcopy(state)
    out = content_references("IEM+phys", state, {"arm": {"crc32": 0xAB, "source": "a"}})
    assert state == before
    assert out["params"]["dynamics"] == "sim.arm:arm_dynamics@arm:000000ab"
    assert out["params"]["ensemble"] == {"reversal": f"{REVERSAL}@arm:000000ab",
                                         "coverage": "sim.coverage:other_velocities"}
    assert out["ensemble"] is state["ensemble"]  # nothing to rewrite: shared
