"""Model files: format, atomic saving, and a clear ModelFileError for every bad file."""

from __future__ import annotations

import copy
import errno
import math
import os
import re
import stat
import zlib
from pathlib import Path

import msgpack
import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from iem import model_kinds, persistence
from iem.ensemble import IncrementalEnsemble
from iem.errors import IemError, ModelFileError
from iem.model_kinds import MODELS
from iem.persistence import SCHEMA, load_model, loads, save_model

K = 12  # samples per point (the tandem simulators give 77; a dozen keeps this fast)


def _setup(n: int = 80, seed: int = 3):
    """A tiny synthetic path (several bags) with linear-in-phi torques."""
    rng = np.random.default_rng(seed)
    s = np.linspace(0.0, 1.0, n)[:, None]
    travel = rng.uniform(-1.0, 1.0, 7)
    travel *= 3.5 / np.linalg.norm(travel)
    Q = rng.uniform(-0.3, 0.3, 7) + s * travel
    dQ = np.gradient(Q, 0.01, axis=0)
    F = Q @ rng.normal(0.0, 0.1, (7, 3))
    C = rng.normal(0.0, 2.0, (7, 7, 10))
    phi = np.column_stack((rng.uniform(0.8, 2.2, K), rng.uniform(-0.05, 0.05, (K, 3)),
                           rng.uniform(0.001, 0.01, (K, 6))))

    def samples_at(i: int):
        A = np.einsum("j,jrc->rc", np.cos(Q[i]), C)
        tau = phi @ A.T
        return np.column_stack((np.tile(Q[i], (K, 1)), np.tile(dQ[i], (K, 1)), tau)), phi.copy()

    X = np.array([samples_at(i)[0][0] for i in range(n)])
    return X, F, samples_at


X_PATH, F_PATH, SAMPLES_AT = _setup()
SPLIT = 50  # learn points [0, SPLIT) before saving, the rest after loading


def _model(**kw) -> IncrementalEnsemble:
    model = IncrementalEnsemble(seed=1, warmup_iters=8, iters=2, fit_epochs=2, **kw)
    model.fit(X_PATH[:20, :7], F_PATH[:20], SAMPLES_AT)
    for i in range(20, SPLIT):
        model.learn_one(X_PATH[i], F_PATH[i], SAMPLES_AT(i))
    return model


MODEL = _model()
VALID = persistence.dumps(MODEL)


def _same_predictions(a, b) -> bool:
    pa = a.predict_many(X_PATH, F_PATH)
    pb = b.predict_many(X_PATH, F_PATH)
    return pa.tobytes() == pb.tobytes()


def _file(tmp_path: Path, data: bytes, name: str = "model.iem") -> Path:
    path = tmp_path / name
    path.write_bytes(data)
    return path


def _head(**changes) -> dict:
    head = msgpack.unpackb(VALID, raw=False)
    head.update(changes)
    return head


def _pack(head: dict) -> bytes:
    return msgpack.packb(head, use_bin_type=True)


def _crc(state: bytes, version: int = persistence.VERSION) -> int:
    """A file's CRC: the state's, continued over the version (not in a version-1 file)."""
    crc = zlib.crc32(state)
    return crc if version == 1 else zlib.crc32(msgpack.packb(version), crc)


def _with_state(state) -> bytes:
    packed = msgpack.packb(state, use_bin_type=True)
    return _pack(_head(state=packed, crc32=_crc(packed)))


class _Toy:
    """A minimal estimator-like model for registry tests."""

    name = "toy"

    def __init__(self, value=None) -> None:
        self.value = value

    def to_state(self) -> dict:
        return {"value": self.value}

    @classmethod
    def from_state(cls, state: dict):
        return cls(state["value"])


TOY = f"{__name__}:_Toy"


# -- round trips -------------------------------------------------------------------------
def test_model_has_several_bags_and_an_open_one():
    assert MODEL.n_bags >= 2
    assert MODEL.open_bag >= 0


def test_round_trip_predicts_and_learns_identically(tmp_path):
    path = tmp_path / "iem.model"
    model = copy.deepcopy(MODEL)
    save_model(model, path)
    loaded = load_model(path)
    assert type(loaded) is IncrementalEnsemble
    assert loaded.params() == model.params()
    assert loaded.n_bags == model.n_bags and loaded.open_bag == model.open_bag
    assert _same_predictions(loaded, model)
    for i in range(SPLIT):
        a = model.predict_one(X_PATH[i], F_PATH[i])
        b = loaded.predict_one(X_PATH[i], F_PATH[i])
        assert a.phi.tobytes() == b.phi.tobytes() and a.bag == b.bag
    # further learning: the open bag keeps training (with noise from the restored RNG),
    # new bags form, and both stay bit-identical
    for i in range(SPLIT, len(X_PATH)):
        model.learn_one(X_PATH[i], F_PATH[i], SAMPLES_AT(i))
        loaded.learn_one(X_PATH[i], F_PATH[i], SAMPLES_AT(i))
        assert _same_predictions(loaded, model)
    assert model.n_bags > MODEL.n_bags
    for bag in range(model.n_bags):
        la, lb = model.learner(bag), loaded.learner(bag)
        assert la.a.tobytes() == lb.a.tobytes() and la.b.tobytes() == lb.b.tobytes()
        assert la._rng.bit_generator.state == lb._rng.bit_generator.state


def test_untrained_model_round_trips(tmp_path):
    model = IncrementalEnsemble(seed=5, input_noise=None)
    save_model(model, tmp_path / "m")
    loaded = load_model(tmp_path / "m")
    assert loaded.n_bags == 0 and loaded.params() == model.params()
    assert np.isnan(loaded.predict_many(X_PATH, F_PATH)).all()


def test_file_layout(tmp_path):
    save_model(MODEL, tmp_path / "m")
    head = msgpack.unpackb((tmp_path / "m").read_bytes(), raw=False)
    assert set(head) == {"schema", "version", "kind", "crc32", "state"}
    assert head["schema"] == SCHEMA == "iem-payload-model"
    assert head["version"] == persistence.VERSION >= 3
    assert head["kind"] == "IEM"
    assert isinstance(head["state"], bytes)
    assert head["crc32"] == _crc(head["state"])
    assert msgpack.unpackb(head["state"], raw=False) == MODEL.to_state()


def test_accepts_str_paths(tmp_path):
    save_model(MODEL, str(tmp_path / "m"))
    assert _same_predictions(load_model(str(tmp_path / "m")), MODEL)


def test_save_over_existing_file_replaces_it_and_leaves_no_temp_files(tmp_path):
    path = tmp_path / "m"
    save_model(IncrementalEnsemble(seed=9), path)
    save_model(MODEL, path)
    assert _same_predictions(load_model(path), MODEL)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m"]


def test_new_file_mode_follows_umask(tmp_path):
    mask = os.umask(0o022)
    try:
        save_model(MODEL, tmp_path / "m")
    finally:
        os.umask(mask)
    assert stat.S_IMODE((tmp_path / "m").stat().st_mode) == 0o644


def test_save_fsyncs_file_and_directory(tmp_path, monkeypatch):
    kinds = []
    real = os.fsync

    def spy(fd):
        kinds.append("dir" if stat.S_ISDIR(os.fstat(fd).st_mode) else "file")
        real(fd)

    monkeypatch.setattr(os, "fsync", spy)
    save_model(MODEL, tmp_path / "m")
    assert kinds == ["file", "dir"]


# -- registry ------------------------------------------------------------------------------
def test_registry_table_names_iem_lazily():
    assert MODELS["IEM"] == "iem.ensemble.model:IncrementalEnsemble"


def test_explicit_registry(tmp_path):
    save_model(_Toy([1.5, "a", None]), tmp_path / "toy")
    with pytest.raises(ModelFileError, match=r"unknown kind 'toy'.*known kinds: .*IEM"):
        load_model(tmp_path / "toy")
    loaded = load_model(tmp_path / "toy", registry={"toy": TOY})
    assert isinstance(loaded, _Toy) and loaded.value == [1.5, "a", None]
    save_model(MODEL, tmp_path / "iem")
    with pytest.raises(ModelFileError, match="unknown kind 'IEM'; known kinds: toy"):
        load_model(tmp_path / "iem", registry={"toy": TOY})


def test_register_model_extends_the_table(tmp_path, monkeypatch):
    monkeypatch.setattr(model_kinds, "MODELS", dict(MODELS))
    model_kinds.register_model("toy", TOY)
    save_model(_Toy(3), tmp_path / "toy")
    assert load_model(tmp_path / "toy").value == 3
    assert "toy" not in MODELS  # the real table was not touched
    with pytest.raises(ValueError, match="module:Class"):
        model_kinds.register_model("bad", "no_colon")


@pytest.mark.parametrize("target", ["no_such_module_xyz:Model", f"{__name__}:Missing",
                                    "no_colon"])
def test_unimportable_kind_is_a_model_file_error(tmp_path, target):
    save_model(_Toy(1), tmp_path / "toy")
    with pytest.raises(ModelFileError, match=r"kind 'toy', registered as .*cannot be imported"):
        load_model(tmp_path / "toy", registry={"toy": target})


# -- bad files -----------------------------------------------------------------------------
def test_missing_file(tmp_path):
    path = tmp_path / "nope.iem"
    with pytest.raises(ModelFileError, match=rf"{path}.*does not exist"):
        load_model(path)


def test_directory_is_not_a_model_file(tmp_path):
    with pytest.raises(ModelFileError, match="is a directory; valid is a regular file"):
        load_model(tmp_path)


def test_empty_file(tmp_path):
    path = _file(tmp_path, b"")
    with pytest.raises(ModelFileError, match=rf"{path} is empty"):
        load_model(path)


def test_garbage_bytes(tmp_path):
    path = _file(tmp_path, b"\xc1\xc1 this is not msgpack")
    with pytest.raises(ModelFileError, match=rf"{path} is not a msgpack model file"):
        load_model(path)


def test_truncated_file(tmp_path):
    path = _file(tmp_path, VALID[: len(VALID) // 2])
    with pytest.raises(ModelFileError, match=r"truncated or corrupt"):
        load_model(path)


def test_trailing_bytes(tmp_path):
    with pytest.raises(ModelFileError, match=r"truncated or corrupt"):
        load_model(_file(tmp_path, VALID + b"\x00"))


def test_not_a_map(tmp_path):
    with pytest.raises(ModelFileError, match=r"holds a list, not the map of a model file"):
        load_model(_file(tmp_path, msgpack.packb([1, 2, 3])))


def test_wrong_schema(tmp_path):
    path = _file(tmp_path, _pack(_head(schema="something-else")))
    with pytest.raises(ModelFileError, match=r"schema 'something-else', expected "
                                             r"'iem-payload-model'"):
        load_model(path)


@pytest.mark.parametrize("version", [0, -1, "1", 1.0, True, None])
def test_unknown_version_says_which_are_supported(tmp_path, version):
    path = _file(tmp_path, _pack(_head(version=version)))
    with pytest.raises(ModelFileError, match=rf"version {version!r}; this build reads versions 1 "
                                             rf"to {persistence.VERSION}"):
        load_model(path)


@pytest.mark.parametrize("version", [1, 2])
def test_a_damaged_version_is_a_corrupt_file_not_another_versions_state(tmp_path, version):
    """The CRC covers the version: a file whose version reads older is refused, not sent
    through that version's migrations."""
    path = _file(tmp_path, _pack(_head(version=version)))
    with pytest.raises(ModelFileError, match=rf"{path} is corrupt: the state's CRC32"):
        load_model(path)
    state = _head()["state"]
    assert loads(_pack(_head(version=version, crc32=_crc(state, version)))).n_bags == MODEL.n_bags


@pytest.mark.parametrize("ahead", [1, 96])
def test_a_newer_version_is_refused_naming_both(tmp_path, ahead):
    version = persistence.VERSION + ahead
    path = _file(tmp_path, _pack(_head(version=version)))
    with pytest.raises(ModelFileError, match=rf"{path} has schema version {version}, newer than "
                                             rf"this build's {persistence.VERSION}: it was "
                                             r"written by a newer iem"):
        load_model(path)


@pytest.mark.parametrize("key", ["schema", "version", "kind", "crc32", "state"])
def test_missing_key(tmp_path, key):
    head = _head()
    del head[key]
    with pytest.raises(ModelFileError, match=rf"lacks the field '{key}'"):
        load_model(_file(tmp_path, _pack(head)))


@pytest.mark.parametrize(("key", "value", "expected"), [
    ("kind", 3, "str"), ("kind", b"IEM", "str"), ("crc32", "123", "int"),
    ("crc32", True, "int"), ("crc32", 1.5, "int"), ("state", "text", "bytes"),
    ("state", {"a": 1}, "bytes"),
])
def test_wrong_types(tmp_path, key, value, expected):
    path = _file(tmp_path, _pack(_head(**{key: value})))
    with pytest.raises(ModelFileError, match=rf"field '{key}' is a .*, expected {expected}"):
        load_model(path)


def test_crc_mismatch(tmp_path):
    head = _head()
    state = bytearray(head["state"])
    state[len(state) // 2] ^= 0x01
    path = _file(tmp_path, _pack(_head(state=bytes(state))))
    with pytest.raises(ModelFileError, match=rf"{path} is corrupt: the state's CRC32"):
        load_model(path)
    path = _file(tmp_path, _pack(_head(crc32=head["crc32"] ^ 1)))
    with pytest.raises(ModelFileError, match="CRC32"):
        load_model(path)


def test_state_not_msgpack_with_valid_crc(tmp_path):
    path = _file(tmp_path, _pack(_head(state=b"\xc1", crc32=_crc(b"\xc1"))))
    with pytest.raises(ModelFileError, match="the state is not valid msgpack"):
        load_model(path)


def test_state_not_a_map(tmp_path):
    with pytest.raises(ModelFileError, match="the state is a list, expected a map"):
        load_model(_file(tmp_path, _with_state([1, 2])))


@pytest.mark.parametrize("drop", ["params", "router", "learners", "open", "out"])
def test_state_missing_part(tmp_path, drop):
    state = MODEL.to_state()
    del state[drop]
    with pytest.raises(ModelFileError, match=r"does not describe a valid IEM model: KeyError"):
        load_model(_file(tmp_path, _with_state(state)))


def test_state_inconsistent(tmp_path):
    state = MODEL.to_state()
    state["learners"] = state["learners"][:-1]
    with pytest.raises(ModelFileError, match=r"bags but .* learners"):
        load_model(_file(tmp_path, _with_state(state)))


def test_model_file_error_is_a_project_error():
    assert issubclass(ModelFileError, IemError)


# -- hypothesis: nothing but ModelFileError escapes for a bad file ------------------------
FUZZ = settings(max_examples=150, deadline=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture])


def _load_or_model_file_error(path: Path, data: bytes):
    path.write_bytes(data)
    try:
        model = load_model(path)
    except ModelFileError as exc:
        assert str(path) in str(exc)
        return None
    return model


@FUZZ
@given(data=st.binary(max_size=512))
def test_random_bytes_only_raise_model_file_error(tmp_path, data):
    assert _load_or_model_file_error(tmp_path / "fuzz", data) is None


@FUZZ
@given(cut=st.integers(0, len(VALID) - 1))
def test_truncations_only_raise_model_file_error(tmp_path, cut):
    assert _load_or_model_file_error(tmp_path / "fuzz", VALID[:cut]) is None


@FUZZ
@given(flips=st.lists(st.tuples(st.integers(0, len(VALID) - 1), st.integers(0, 7)),
                      min_size=1, max_size=3))
def test_bit_flips_only_raise_model_file_error(tmp_path, flips):
    data = bytearray(VALID)
    for pos, bit in flips:
        data[pos] ^= 1 << bit
    model = _load_or_model_file_error(tmp_path / "fuzz", bytes(data))
    if bytes(data) != VALID:
        assert model is None  # CRC32 (distance 4 at this length) or the header checks


_leaves = (st.none() | st.booleans() | st.integers(-2**63, 2**64 - 1) | st.floats()
           | st.text(max_size=8) | st.binary(max_size=8))
_plain = st.recursive(_leaves, lambda inner: st.lists(inner, max_size=4)
                      | st.dictionaries(st.text(max_size=6), inner, max_size=4), max_leaves=20)


STATE_ERROR = re.compile(r"the state is a \w+, expected a map|the state does not describe a "
                         r"valid IEM model: \w+|the state's .+ (holds|is|has) |the state "
                         r"holds the unknown key")
"""What a file with an intact header and CRC but a bad state raises (after its path)."""


def _load_or_error(path: Path, data: bytes):
    """The model in ``data`` written to ``path``, or the ModelFileError it raised (which must
    name the path)."""
    path.write_bytes(data)
    try:
        return load_model(path)
    except ModelFileError as exc:
        assert str(path) in str(exc)
        return exc


@FUZZ
@given(state=_plain)
def test_random_states_with_valid_crc_raise_the_state_error(tmp_path, state):
    error = _load_or_error(tmp_path / "fuzz", _with_state(state))
    assert isinstance(error, ModelFileError)  # random plain data never describe a model
    assert STATE_ERROR.search(str(error)), str(error)


def _paths(obj, prefix=()):
    yield prefix
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from _paths(v, (*prefix, k))
    elif isinstance(obj, list) and len(obj) <= 12:
        for i, v in enumerate(obj):
            yield from _paths(v, (*prefix, i))


STATE = MODEL.to_state()
STATE_PATHS = [p for p in _paths(STATE) if p]


LEARNER_ARRAYS = ("lo", "hi", "center", "scale", "a", "b", "input_noise", "dq_precision")
"""The numbers a weak learner keeps; the router keeps its bags' means, the model the output
scaling ``out``: what a model learnt."""


def _learnt(where: tuple) -> bool:
    """``where`` lies in the numbers a model learnt."""
    if where[0] == "learners":
        return len(where) > 2 and where[2] in LEARNER_ARRAYS
    return where[0] == "out" or where[:2] == ("router", "means")


def _learnt_numbers(state: dict):
    """Every leaf of the learnt numbers of a model's state."""
    def leaves(v):
        if isinstance(v, list):
            for x in v:
                yield from leaves(x)
        elif v is not None:
            yield v

    yield from leaves(state["router"]["means"])
    yield from leaves(state["out"])
    for learner in state["learners"]:
        for key in LEARNER_ARRAYS:
            yield from leaves(learner.get(key))


def _at(state, where: tuple):
    for key in where:
        state = state[key]
    return state


def _finite_number(value) -> bool:
    return isinstance(value, int | float) and math.isfinite(value)


@FUZZ
@example(where=("learners", 0, "b", 3), value=None, delete=False)  # None where a number was
@example(where=("router", "means", 1, 2), value=math.nan, delete=False)
@example(where=("out", 1, 7), value={}, delete=False)
@example(where=("out",), value=[], delete=False)
@example(where=("learners", 1, "a", 0, 5), value=0.25, delete=False)  # another number
@example(where=("params", "rho"), value=None, delete=True)  # a file made before a parameter
@given(where=st.sampled_from(STATE_PATHS), value=_plain, delete=st.booleans())
def test_mutated_states_load_as_written_or_raise_the_state_error(tmp_path, where, value, delete):
    state = copy.deepcopy(STATE)
    parent = _at(state, where[:-1])
    delete = delete and isinstance(parent, dict)
    if delete:
        del parent[where[-1]]
    else:
        parent[where[-1]] = value
    outcome = _load_or_error(tmp_path / "fuzz", _with_state(state))
    if isinstance(outcome, ModelFileError):  # the header and CRC are intact: the state's fault
        assert STATE_ERROR.search(str(outcome)), str(outcome)
        return
    # a file that loads holds a model that estimates, its learnt numbers all finite ...
    loaded = outcome.to_state()
    assert all(type(v) is float and math.isfinite(v) for v in _learnt_numbers(loaded))
    assert outcome.predict_many(X_PATH[:5], F_PATH[:5]).shape == (5, 10)
    # ... and what the file says: a parameter it lacks at its default, a number as written
    if delete and where[0] == "params":
        assert loaded["params"][where[1]] == IncrementalEnsemble().params()[where[1]]
    elif not delete and _learnt(where) and _finite_number(value) \
            and isinstance(_at(STATE, where), float):
        assert _at(loaded, where) == float(value)


# -- failed saves leave the old file alone -------------------------------------------------
OLD = IncrementalEnsemble(seed=2, warmup_iters=5, iters=1, input_noise=None)
OLD.learn_one(X_PATH[0], F_PATH[0], SAMPLES_AT(0))


def _assert_old_file_intact(tmp_path: Path, path: Path) -> None:
    assert _same_predictions(load_model(path), OLD)
    assert sorted(p.name for p in tmp_path.iterdir()) == [path.name], "temp file left behind"


def test_unpackable_state_is_a_model_file_error(tmp_path):
    path = tmp_path / "m"
    save_model(OLD, path)
    with pytest.raises(ModelFileError, match=rf"cannot save model to {path}.*not plain data"):
        save_model(_Toy(np.zeros(3)), path)
    with pytest.raises(ModelFileError, match="not plain data"):
        save_model(_Toy(2**70), path)
    with pytest.raises(ModelFileError, match="no str 'name'"):
        save_model(object(), path)
    _assert_old_file_intact(tmp_path, path)


def test_crash_in_replace_keeps_old_file(tmp_path, monkeypatch):
    path = tmp_path / "m"
    save_model(OLD, path)

    def crash(src, dst):
        raise OSError(errno.EIO, "simulated crash during rename")

    monkeypatch.setattr(os, "replace", crash)
    with pytest.raises(ModelFileError, match=rf"{path}.*simulated crash during rename"):
        save_model(MODEL, path)
    monkeypatch.undo()
    _assert_old_file_intact(tmp_path, path)


def test_disk_full_during_write_keeps_old_file(tmp_path, monkeypatch):
    path = tmp_path / "m"
    save_model(OLD, path)
    real_fdopen = os.fdopen

    class Full:
        def __init__(self, fh):
            self._fh = fh

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self._fh.close()

        def write(self, data):
            self._fh.write(data[: len(data) // 2])
            raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "fdopen", lambda fd, mode: Full(real_fdopen(fd, mode)))
    with pytest.raises(ModelFileError, match=rf"{path}: No space left on device"):
        save_model(MODEL, path)
    monkeypatch.undo()
    _assert_old_file_intact(tmp_path, path)


def test_fsync_failure_keeps_old_file(tmp_path, monkeypatch):
    path = tmp_path / "m"
    save_model(OLD, path)

    def fail(fd):
        raise OSError(errno.EIO, "Input/output error")

    monkeypatch.setattr(os, "fsync", fail)
    with pytest.raises(ModelFileError, match="Input/output error"):
        save_model(MODEL, path)
    monkeypatch.undo()
    _assert_old_file_intact(tmp_path, path)


def test_interrupt_mid_save_keeps_old_file(tmp_path, monkeypatch):
    path = tmp_path / "m"
    save_model(OLD, path)

    def interrupt(src, dst):
        raise KeyboardInterrupt

    monkeypatch.setattr(os, "replace", interrupt)
    with pytest.raises(KeyboardInterrupt):
        save_model(MODEL, path)
    monkeypatch.undo()
    _assert_old_file_intact(tmp_path, path)


def test_read_only_directory(tmp_path, monkeypatch):
    folder = tmp_path / "ro"
    folder.mkdir()
    path = folder / "m"
    save_model(OLD, path)
    folder.chmod(0o555)
    try:
        if os.access(folder, os.W_OK):  # root ignores the mode: refuse the create ourselves
            real_open = os.open

            def refuse(file, flags, *args, **kw):
                if flags & os.O_CREAT:
                    raise PermissionError(errno.EACCES, "Permission denied", str(file))
                return real_open(file, flags, *args, **kw)

            monkeypatch.setattr(os, "open", refuse)
        with pytest.raises(ModelFileError, match=rf"{path}: Permission denied"):
            save_model(MODEL, path)
        monkeypatch.undo()
        assert _same_predictions(load_model(path), OLD)
        assert sorted(p.name for p in folder.iterdir()) == ["m"]
    finally:
        folder.chmod(0o755)


def test_missing_directory(tmp_path):
    with pytest.raises(ModelFileError, match="No such file or directory"):
        save_model(MODEL, tmp_path / "nope" / "m")


def test_directory_fsync_not_supported_is_tolerated(tmp_path, monkeypatch):
    real = os.fsync

    def no_dir_sync(fd):
        if stat.S_ISDIR(os.fstat(fd).st_mode):
            raise OSError(errno.EINVAL, "Invalid argument")
        real(fd)

    monkeypatch.setattr(os, "fsync", no_dir_sync)
    save_model(MODEL, tmp_path / "m")
    monkeypatch.undo()
    assert _same_predictions(load_model(tmp_path / "m"), MODEL)


def test_loads_names_its_source():
    with pytest.raises(ModelFileError, match="model file <bytes> is empty"):
        loads(b"")
    assert _same_predictions(loads(VALID), MODEL)


def test_new_model_selects_a_kind_by_name():
    from iem.baselines.least_squares import RecursiveLeastSquares
    from iem.errors import InvalidInputError
    from iem.model_kinds import DEFAULT_MODEL, new_model
    from iem.physics import PhysicsInformedEnsemble

    assert DEFAULT_MODEL == "IEM+phys" and DEFAULT_MODEL in MODELS
    from sim.arm import NOMINAL_DYNAMICS

    assert isinstance(new_model(dynamics=NOMINAL_DYNAMICS), PhysicsInformedEnsemble)
    ls = new_model("LS", dynamics=NOMINAL_DYNAMICS, cutoff_hz=10.0)
    assert isinstance(ls, RecursiveLeastSquares) and ls.cutoff_hz == 10.0
    with pytest.raises(InvalidInputError, match="needs dynamics"):
        new_model("LS", cutoff_hz=10.0)
    with pytest.raises(InvalidInputError, match=r"unknown model kind 'nope'.*IEM\+phys"):
        new_model("nope")
    with pytest.raises(InvalidInputError, match="does not take"):
        new_model("LS", dynamics=NOMINAL_DYNAMICS, no_such_option=1)


# -- the estimators are given their robot's dynamics; a model file stores them ----------------
def _physics(dynamics):
    from iem.physics import PhysicsInformedEnsemble

    return PhysicsInformedEnsemble(dynamics=dynamics)


def _least_squares(dynamics):
    from iem.baselines.least_squares import RecursiveLeastSquares

    return RecursiveLeastSquares(dynamics)


def _regression(dynamics):
    from iem.physics.regression import PayloadRegression

    return PayloadRegression(dynamics)


@pytest.mark.parametrize("build", [
    _physics, _least_squares, _regression,
    lambda d: model_kinds.new_model("IEM+phys", dynamics=d),
    lambda d: model_kinds.new_model("LS", dynamics=d)],
    ids=["IEM+phys", "LS", "regression", "new_model IEM+phys", "new_model LS"])
def test_an_estimator_without_dynamics_refuses_saying_what_it_needs(build):
    from iem.errors import InvalidInputError
    from sim.arm import NOMINAL_DYNAMICS

    for missing in (None, "sim.robot.panda_dynamics", 3, NOMINAL_DYNAMICS + "@ARG",
                    "sim.arm:arm_dynamics@/abs/arm.msgpack", "os:system@true"):
        with pytest.raises(InvalidInputError, match=r"needs dynamics, the robot's model: .*"
                                                    r"valid are .*sim\.arm:arm_dynamics"):
            build(missing)
    assert build(NOMINAL_DYNAMICS).dynamics == NOMINAL_DYNAMICS
    named = "sim.arm:nominal_dynamics@none"
    assert build(named).dynamics == named


def test_a_model_file_stores_the_dynamics_it_was_given():
    model = _least_squares("sim.arm:nominal_dynamics@franka_hand")
    assert loads(persistence.dumps(model)).dynamics == "sim.arm:nominal_dynamics@franka_hand"
