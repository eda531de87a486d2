"""Model files read within bounds (:mod:`iem.persistence`, :mod:`iem.state_checks`): a size
limit before anything is read, a regular file only, unknown keys refused at every level
(the header, its arm record, the state, a learner), every number of the state checked
(finite, in range, covariances positive semidefinite), and unpacking that stops before a
file of tiny containers fills the memory."""

from __future__ import annotations

import os
import struct
import tracemalloc
import zlib

import msgpack
import numpy as np
import pytest

from iem import persistence, state_checks
from iem.errors import ModelFileError
from iem.persistence import MAX_MODEL_BYTES, load_model, loads, save_model
from tests.iem.test_checks import DATA, ESTIMATORS
from tests.watchdog import within


@pytest.fixture(scope="module")
def phys_bytes() -> bytes:
    """A trained IEM+phys's model file, with a posterior and a payload it started from."""
    from iem.check_data import train

    model = train(ESTIMATORS["IEM+phys"](), DATA)
    model.start_from(np.array([1.0, 0.0, 0.0, 0.05, 0.01, 0.0, 0.0, 0.01, 0.0, 0.01]),
                     np.full(10, 0.01))
    return persistence.dumps(model)


def head_of(data: bytes) -> dict:
    return msgpack.unpackb(data, raw=False)


def state_of(data: bytes) -> dict:
    return msgpack.unpackb(head_of(data)["state"], raw=False, strict_map_key=False)


def with_state(data: bytes, state=None, raw: bytes | None = None) -> bytes:
    """The model file ``data`` with another state (packed, or the bytes ``raw``), its CRC
    made right: only the state's checks can refuse it."""
    head = head_of(data)
    head["state"] = raw if raw is not None else msgpack.packb(state, use_bin_type=True)
    head["crc32"] = persistence._record_crc(head.get("arm"), zlib.crc32(head["state"]),
                                           head.get("family"), head["version"])
    return msgpack.packb(head, use_bin_type=True)


# -- what is read: a regular file, within the size limit -----------------------------------
def test_a_file_over_the_size_limit_is_refused_before_it_is_read(tmp_path):
    path = tmp_path / "huge.msgpack"
    with open(path, "wb") as f:  # sparse: no disk, and reading it would take seconds
        f.truncate(MAX_MODEL_BYTES + 1)
    with within(5), pytest.raises(ModelFileError, match=rf"{path}: cannot read the model file: "
                                                        "it holds 32 MB; valid is at most 32 MB"):
        load_model(path)


def test_the_size_limit_is_far_above_a_real_model(phys_bytes):
    assert MAX_MODEL_BYTES == 32 * 1024 * 1024 > 20 * len(phys_bytes)


def test_a_device_is_refused_without_reading_it():
    with within(5), pytest.raises(ModelFileError, match="/dev/zero: cannot read the model file: "
                                                        "it is a character device; valid is a "
                                                        "regular file"):
        load_model("/dev/zero")


def test_a_fifo_is_refused_without_waiting_for_a_writer(tmp_path):
    fifo = tmp_path / "model.msgpack"
    os.mkfifo(fifo)
    with within(5), pytest.raises(ModelFileError, match="it is a FIFO \\(named pipe\\); valid "
                                                        "is a regular file"):
        load_model(fifo)


def test_a_directory_is_refused(tmp_path):
    with pytest.raises(ModelFileError, match="it is a directory; valid is a regular file"):
        load_model(tmp_path)


# -- unknown keys, at every level ----------------------------------------------------------
def test_an_unknown_header_field_is_refused_before_its_value_is_read(phys_bytes):
    """A header holding a million empty arrays under an unknown key (2.2 GB for 30 MB before
    the check): refused by its name, nothing of it unpacked."""
    n = 1_000_000
    packed = msgpack.packb(head_of(phys_bytes), use_bin_type=True)
    assert packed[0] & 0xF0 == 0x80  # a fixmap: one more entry
    bomb = bytes([packed[0] + 1]) + packed[1:] + b"\xa4junk\xdd" + struct.pack(">I", n) \
        + b"\x90" * n
    tracemalloc.start()
    try:
        with pytest.raises(ModelFileError, match="has the unknown field 'junk'; valid are "):
            loads(bomb)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 4 * len(bomb), peak


@pytest.mark.parametrize("where", ["header", "arm record", "state", "learner", "params",
                                   "nested map"])
def test_an_unknown_key_is_refused_at_every_level(phys_bytes, where):
    head, state = head_of(phys_bytes), state_of(phys_bytes)
    expected = {"header": "has the unknown field 'note'; valid are arm, crc32, family",
                "arm record": "field 'arm' holds the unknown key(s) ['note']",
                "state": "the state holds the unknown key(s) zzz",
                "learner": "the state holds the unknown key(s) ensemble.learners[1].zzz",
                "params": "unexpected keyword argument 'zzz'",
                "nested map": "the state holds the unknown key(s) detector.zzz"}[where]
    if where == "header":
        data = msgpack.packb({**head, "note": "hi"}, use_bin_type=True)
    elif where == "arm record":
        head["arm"] = {"crc32": 1, "source": "arm.msgpack", "note": "x"}
        data = msgpack.packb(head, use_bin_type=True)
    else:
        target = {"state": state, "learner": state["ensemble"]["learners"][1],
                  "params": state["params"], "nested map": state["detector"]}[where]
        target["zzz"] = [1.0]
        data = with_state(phys_bytes, state)
    with pytest.raises(ModelFileError, match=expected.replace("[", r"\[").replace("]", r"\]")
                       .replace("(", r"\(").replace(")", r"\)")):
        loads(data)


# -- every number checked ------------------------------------------------------------------
EYE = np.eye(10).tolist()
NUMBERS = {
    "nan covariance": (("post", "cov"), np.full((10, 10), np.nan).tolist(),
                       "post.cov holds 100 value(s) that are not finite numbers"),
    "negative covariance": (("post", "cov"), (-np.eye(10)).tolist(),
                            "post.cov has the eigenvalue -1; valid: a positive semidefinite"),
    "asymmetric precision": (("post", "precision"), np.triu(np.ones((10, 10))).tolist(),
                             "post.precision is not symmetric"),
    "negative initial covariance": (("initial",), [[0.5] + [0.0] * 9, (-np.eye(10)).tolist()],
                                    "initial has the eigenvalue -1"),
    "negative information": (("info",), (-1e12 * np.eye(10)).tolist(),
                             "info has the eigenvalue -1e+12"),
    "nan torque spread": (("params", "sigma_tau"), float("nan"),
                          "params.sigma_tau holds 1 value(s) that are not finite"),
    "negative torque spread": (("params", "sigma_tau"), -0.05,
                               "params.sigma_tau holds -0.05; valid: a torque spread in N·m, "
                               "numbers in (0, 1000]"),
    "nan in a sum": (("eta",), [float("nan")] + [0.0] * 9, "eta holds 1 value(s)"),
    "negative count": (("m",), -5, "m holds -5; valid: a count, integers from 0 to 1e+11"),
    "count of 1e12": (("m",), 10**12, "m holds 1e+12; valid: a count"),
    "fractional count": (("n",), 2.5, "n holds a value that is not an integer"),
    "reservoir of 1e12": (("ensemble", "params", "reservoir"), 10**12,
                          "ensemble.params.reservoir holds 1e+12; valid: samples kept, "
                          "integers from 0 to 100000"),
    "rate of 1e12 Hz": (("params", "rate_hz"), 1e12, "params.rate_hz holds 1e+12; valid: a "
                                                     "rate in Hz, numbers in (0, 100000]"),
    "negative bag count": (("ensemble", "router", "counts"), [-3, 5],
                           "ensemble.router.counts holds -3"),
    "infinite weight": (("ensemble", "learners", 0, "a"), [[float("inf")] * 21] * 10,
                        "ensemble.learners.a holds 210 value(s) that are not finite"),
}


@pytest.mark.parametrize("case", sorted(NUMBERS))
def test_every_number_of_the_state_is_checked(phys_bytes, case):
    keys, value, message = NUMBERS[case]
    state = state_of(phys_bytes)
    if state["post"] is None:  # a valid posterior to break
        state["post"] = {"mean": [0.5] + [0.0] * 9, "cov": EYE, "precision": EYE,
                         "inflation": 1.0, "equations": 0}
        loads(with_state(phys_bytes, state))
    target = state
    for key in keys[:-1]:
        target = target[key]
    target[keys[-1]] = value
    with pytest.raises(ModelFileError, match=message.replace("(", r"\(").replace(")", r"\)")
                       .replace("+", r"\+")):
        loads(with_state(phys_bytes, state))


def test_every_number_a_model_saves_has_a_rule():
    """Each kind's state, trained, with a posterior, a payload started from, a calibrated
    arm's torque noise and a bag budget, and an IEM+phys whose arm carries its calibration's
    posterior, saved between an alarm and the data's choice (a candidate held): every key
    that holds numbers has its rule, so a new field cannot slip past the checks unnoticed
    (give it one in iem.state_checks.RULES)."""
    from iem.check_data import train
    from iem.physics import PhysicsInformedEnsemble
    from iem.physics.torque_noise import NOMINAL_ARM_NOISE
    from sim.arm import NOMINAL_DYNAMICS, POSTERIOR_PARAMS, ArmParams, arm_spec
    from sim.friction import full_friction

    nominal = ArmParams.nominal()
    arm = ArmParams(nominal.link_params, full_friction(np.zeros((7, 3))), np.zeros(7),
                    {"source": "a test's"}, end_effector=nominal.end_effector,
                    posterior=np.eye(POSTERIOR_PARAMS) * 1e-6)
    makers = dict(ESTIMATORS)
    makers["IEM+phys calibrated, budget"] = lambda: PhysicsInformedEnsemble(
        ensemble={"seed": 0, "fit_epochs": 2, "warmup_iters": 10, "iters": 2,
                  "budget_bags": 3, "probation_bags": 1},
        dynamics=NOMINAL_DYNAMICS, torque_noise=NOMINAL_ARM_NOISE.to_dict())
    makers["IEM+phys, an arm's posterior, a candidate"] = lambda: PhysicsInformedEnsemble(
        ensemble={"seed": 0, "fit_epochs": 2, "warmup_iters": 10, "iters": 2},
        dynamics=arm_spec(arm), torque_noise=NOMINAL_ARM_NOISE.to_dict())
    for name, make in makers.items():
        model = train(make(), DATA)
        if "candidate" in name:
            model = holding_a_candidate(model)
            assert model._candidate.window.m, name
        if model.starts_from_payload and "candidate" not in name:
            model.start_from(np.array([1.0, 0, 0, 0.05, 0.01, 0, 0, 0.01, 0, 0.01]),
                             np.full(10, 0.01))
        state = msgpack.unpackb(msgpack.packb(model.to_state(), use_bin_type=True),
                                raw=False, strict_map_key=False)
        keys = {".".join(path) for path, _ in state_checks.numbers_in(state)}
        assert keys, name
        missing = sorted(k for k in keys if state_checks.rule_of(tuple(k.split("."))) is None)
        assert not missing, (name, missing)
        state_checks.check_state(state)  # and a real model passes them


def holding_a_candidate(model):
    """``model`` (a trained IEM+phys) learning the further points until it holds a candidate,
    between an alarm and the data's choice (the synthetic data raise alarms)."""
    from iem.check_data import learn

    for i in DATA.further_points():
        learn(model, DATA, i)
        if model._candidate is not None:
            return model
    raise AssertionError("no alarm in the further points: nothing to hold a candidate")


@pytest.fixture(scope="module")
def candidate_bytes() -> bytes:
    """An IEM+phys's model file that holds a candidate."""
    from iem.check_data import train
    from iem.physics import PhysicsInformedEnsemble
    from iem.physics.torque_noise import NOMINAL_ARM_NOISE
    from sim.arm import NOMINAL_DYNAMICS

    return persistence.dumps(holding_a_candidate(train(PhysicsInformedEnsemble(
        ensemble={"seed": 0, "fit_epochs": 2, "warmup_iters": 10, "iters": 2},
        dynamics=NOMINAL_DYNAMICS, torque_noise=NOMINAL_ARM_NOISE.to_dict()), DATA)))


@pytest.mark.parametrize(("case", "message"), [
    ("intact", None),
    ("unknown key", "the state holds the unknown key(s) candidate.zzz"),
    ("negative count", "candidate.samples holds -1; valid: a count"),
    ("negative covariance", "candidate.post.cov has the eigenvalue -1"),
    ("nan evidence", "candidate.evidence holds 1 value(s) that are not finite"),
])
def test_a_candidate_in_the_file_is_read_as_every_state_is(candidate_bytes, case, message):
    state = state_of(candidate_bytes)
    cand = state["candidate"]
    assert cand is not None and cand["window"]["m"] > 0
    if case == "unknown key":
        cand["zzz"] = [1.0]
    elif case == "negative count":
        cand["samples"] = -1
    elif case == "negative covariance":
        cand["post"]["cov"] = (-np.eye(10)).tolist()
    elif case == "nan evidence":
        cand["evidence"] = float("nan")
    data = with_state(candidate_bytes, state)
    if message is None:
        assert loads(data)._candidate.window.m == cand["window"]["m"]
        return
    with pytest.raises(ModelFileError, match=message.replace("(", r"\(").replace(")", r"\)")):
        loads(data)


# -- unpacking within bounds ---------------------------------------------------------------
def test_a_state_of_tiny_containers_stops_unpacking_within_its_budget(phys_bytes):
    """Two million empty arrays inside the state, under a known key and a valid CRC: the
    unpacking stops at its budget (8 times the state's size and 4 MB), not at 150 MB."""
    state = msgpack.packb(state_of(phys_bytes), use_bin_type=True)
    assert state[0] == 0xDE  # map16: one more entry
    n = struct.unpack(">H", state[1:3])[0]
    inner = (b"\xdd" + struct.pack(">I", 100_000) + b"\x90" * 100_000) * 20
    raw = b"\xde" + struct.pack(">H", n + 1) + state[3:] + b"\xa3zzz\xdc" \
        + struct.pack(">H", 20) + inner
    data = with_state(phys_bytes, raw=raw)
    tracemalloc.start()
    try:
        with pytest.raises(ModelFileError, match="the state unpacks to more than"):
            loads(data)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 3 * (8 * len(raw) + 4 * 2**20), peak


def test_a_huge_list_in_the_state_is_refused_by_its_length(phys_bytes):
    raw = msgpack.packb({"learners": [0] * (2**20 + 1)}, use_bin_type=True)
    with pytest.raises(ModelFileError, match="a list or map of 1048577 values; valid is at "
                                             "most 1048576"):
        loads(with_state(phys_bytes, raw=raw))


# -- the files that were fine load as they did ---------------------------------------------
@pytest.mark.parametrize("kind", sorted(ESTIMATORS))
def test_every_kind_still_loads(tmp_path, kind):
    from iem.check_data import train

    model = train(ESTIMATORS[kind](), DATA)
    save_model(model, tmp_path / "m.msgpack")
    loaded = load_model(tmp_path / "m.msgpack")
    assert type(loaded) is type(model) and loaded.n_bags == model.n_bags
