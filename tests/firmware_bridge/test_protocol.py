"""The DBC and the codecs built from it, checked against cantools' own encoder and decoder."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_bridge.can_link import CanDecoder
from firmware_bridge.errors import BridgeConfigError, EncodeError
from firmware_bridge.protocol import PROFILES, LoadAssembler, database, profile
from iem.types import NOMINAL_RATE_HZ, JointState
from sim.family import default_test_payload, training_payloads
from sim.payload import Payload
from sim.plant import SensorModel
from sim.robot import arm_model

from .conftest import cantools_cycle, cantools_frame, data_ids, joint_signals

Q = st.floats(-5.24, 5.24)
DQ = st.floats(-3.27, 3.27)
TAU = st.floats(-327.0, 327.0)
vec = lambda s: st.lists(s, min_size=7, max_size=7)  # noqa: E731


def test_the_dbc_loads_strictly_and_every_frame_is_protected():
    db = database()
    names = {m.name for m in db.messages}
    assert {"JointStateFD", "JointStateHeader", "Heartbeat", "LoadCommand", "LoadAck"} <= names
    for m in db.messages:
        assert m.signals[0].name == "E2E_CRC" and m.signals[0].start == 0
        assert m.get_signal_by_name("E2E_Counter").start == 8
    assert db.get_message_by_name("JointStateFD").is_fd
    assert db.get_message_by_name("JointStateFD").length == 64
    assert all(db.get_message_by_name(f"JointState{j}").length == 8 for j in range(1, 8))


def test_unknown_profile_names_the_valid_ones():
    with pytest.raises(BridgeConfigError, match="valid profiles are fd, classic"):
        profile("can-xl")


def test_resolution_is_below_the_sensor_noise_and_ranges_cover_the_panda():
    sensor, arm = SensorModel(), arm_model()
    for name in PROFILES:
        f = profile(name).joint_state.fields
        for j in range(1, 8):
            q, dq, tau = f[f"Q{j}"], f[f"DQ{j}"], f[f"Tau{j}"]
            assert q.scale <= 1e-5 and dq.scale <= 1e-4 and tau.scale <= 0.01
            assert q.scale < sensor.sigma_q and dq.scale < sensor.sigma_dq
            assert tau.scale < sensor.sigma_tau
            assert q.raw_min * q.scale < arm.q_min[j - 1] and q.raw_max * q.scale > arm.q_max[j - 1]
            assert dq.raw_max * dq.scale > arm.dq_max[j - 1]
            assert tau.raw_max * tau.scale > 87.0  # the Panda's largest joint torque, N·m


def test_the_rates_come_from_the_dbc():
    assert profile("fd").joint_state.rate_hz == 1000 and profile("fd").joint_state.stride == 1
    assert profile("classic").joint_state.rate_hz == 500
    assert profile("classic").joint_state.stride == 2


def test_the_fd_rate_is_the_estimators_nominal_rate():
    """The DBC's fd cycle and the rate every filter and estimator defaults to are one rate."""
    assert profile("fd").joint_state.rate_hz == NOMINAL_RATE_HZ


@pytest.mark.parametrize("name", PROFILES)
@settings(max_examples=60, deadline=None)
@given(cycle=st.integers(0, 2**32 - 1), time_us=st.integers(0, 2**20 - 1), q=vec(Q),
       dq=vec(DQ), tau=vec(TAU), counter=st.integers(0, 15))
def test_decoding_matches_frames_encoded_by_cantools(name, cycle, time_us, q, dq, tau, counter):
    signals = joint_signals(cycle, time_us * 1e-6, q, dq, tau)
    decoder = CanDecoder(name)
    states = [decoder.push(m) for m in cantools_cycle(name, signals, counter)]
    assert states[:-1] == [None] * (len(states) - 1)
    s = states[-1]
    assert s.cycle == cycle
    assert s.t == pytest.approx(time_us * 1e-6, abs=1e-9)
    np.testing.assert_allclose(s.q, q, atol=0.5e-5 + 1e-12)
    np.testing.assert_allclose(s.dq, dq, atol=0.5e-4 + 1e-12)
    np.testing.assert_allclose(s.tau_J, tau, atol=0.5e-2 + 1e-12)
    assert decoder.counters.delivered == 1 and not decoder.counters.dropped()


@pytest.mark.parametrize("name", PROFILES)
@settings(max_examples=40, deadline=None)
@given(cycle=st.integers(0, 2**32 - 1), q=vec(Q), dq=vec(DQ), tau=vec(TAU),
       counter=st.integers(0, 15))
def test_encoding_is_read_back_by_cantools(name, cycle, q, dq, tau, counter):
    js = profile(name).joint_state
    state = JointState(t=123.456789, q=q, dq=dq, tau_J=tau, cycle=cycle)
    frames, saturated = js.encode(state, counter)
    assert saturated == 0
    db = database()
    got = {}
    for codec, data in frames:
        msg = db.get_message_by_frame_id(codec.frame_id)
        ids = data_ids(msg)
        from cantools.autosar.end_to_end import check_profile2_crc

        assert check_profile2_crc(data, ids[counter])
        got.update(msg.decode(data))
    assert got["Cycle"] == cycle
    for j in range(7):
        assert got[f"Q{j + 1}"] == pytest.approx(q[j], abs=0.5e-5 + 1e-12)
        assert got[f"DQ{j + 1}"] == pytest.approx(dq[j], abs=0.5e-4 + 1e-12)
        assert got[f"Tau{j + 1}"] == pytest.approx(tau[j], abs=0.5e-2 + 1e-12)
    wrapped = round(123.456789e6) % (1 << js.time_bits)
    assert got["Time"] == pytest.approx(wrapped * 1e-6, abs=1e-9)


def test_values_out_of_range_are_saturated_and_counted():
    js = profile("fd").joint_state
    state = JointState(t=0.0, q=[9, 0, 0, 0, 0, 0, -9], dq=np.zeros(7), tau_J=np.zeros(7))
    frames, saturated = js.encode(state, 0)
    assert saturated == 2
    s = CanDecoder("fd").push(__import__("can").Message(
        arbitration_id=0x100, data=frames[0][1], is_fd=True, is_extended_id=False))
    assert s.q[0] == pytest.approx(5.24287) and s.q[6] == pytest.approx(-5.24288)


def _payload_signals(p):
    return {"Mass": p.mass, "ComX": p.com[0], "ComY": p.com[1], "ComZ": p.com[2],
            **dict(zip(("Ixx", "Ixy", "Ixz", "Iyy", "Iyz", "Izz"), p.inertia, strict=True))}


def _close(a: Payload, b: Payload) -> None:
    assert a.mass == pytest.approx(b.mass, abs=0.5e-4 + 1e-12)
    np.testing.assert_allclose(a.com, b.com, atol=0.5e-5 + 1e-12)
    np.testing.assert_allclose(a.inertia, b.inertia, atol=0.5e-6 + 1e-12)


@pytest.mark.parametrize("name", PROFILES)
def test_payload_command_both_ways_against_cantools(name):
    codec = profile(name).command
    db = database()
    msg = db.get_message_by_frame_id(codec.frame.frame_id)
    for k, p in enumerate([default_test_payload(), *training_payloads()[:10]]):
        seq = 1 + k
        # mine -> cantools
        frames, _ = codec.encode(seq, p, counter=k)
        got = {}
        for data in frames:
            got.update(msg.decode(data))
        assert got["Seq"] == seq
        _close(Payload("x", got["Mass"], (got["ComX"], got["ComY"], got["ComZ"]),
                       tuple(got[n] for n in ("Ixx", "Ixy", "Ixz", "Iyy", "Iyz", "Izz"))), p)
        # cantools -> mine
        assembler = LoadAssembler(codec)
        sig = {"Seq": seq, **_payload_signals(p)}
        raw = None
        muxes = sorted(codec.frame.layouts) if codec.frame.mux is not None else [None]
        for i, mux in enumerate(muxes):
            mine = {s.name: sig[s.name] for s in msg.signals
                    if s.name in sig and (mux is None or s.multiplexer_ids in (None, [mux]))}
            if mux is not None:
                mine["Mux"] = mux
            raw = assembler.push(cantools_frame(msg.name, mine, (k + i) % 16).data)
        got_seq, _, load = codec.values(raw)
        assert got_seq == seq
        _close(load, p)


@pytest.mark.parametrize("name", PROFILES)
def test_payloads_that_do_not_fit_are_refused_with_the_valid_range(name):
    codec = profile(name).command
    big = Payload("big", 2.0, (0.0, 0.0, 0.1), (0.9, 0.0, 0.0, 0.9, 0.0, 0.9))
    with pytest.raises(EncodeError, match=r"Ixx.*valid is \[-0.524288, 0.524287\]"):
        codec.encode(1, big, 0)
    tiny = Payload("tiny", 1e-6, (0, 0, 0), (1e-9, 0, 0, 1e-9, 0, 1e-9))
    with pytest.raises(EncodeError, match="rounds to 0"):
        codec.encode(1, tiny, 0)
    nan = Payload("nan", math.nan, (0, 0, 0), (1, 0, 0, 1, 0, 1))
    with pytest.raises(EncodeError, match="Mass"):
        codec.encode(1, nan, 0)


@pytest.mark.parametrize("name", PROFILES)
def test_clearing_the_load_is_mass_zero(name):
    codec = profile(name).ack
    frames, _ = codec.encode(9, None, 0, status=0)
    assembler = LoadAssembler(codec)
    raws = [assembler.push(f) for f in frames]
    assert codec.values(raws[-1]) == (9, 0, None)


def test_heartbeat_round_trip_against_cantools():
    hb = profile("fd").heartbeat
    data = hb.encode("holding", 7, 2**32 + 5, 1000, counter=4)
    got = database().get_message_by_name("Heartbeat").decode(data)
    assert got["State"] == "holding" and got["LoadSeq"] == 7
    assert got["Cycle"] == 5 and got["Overruns"] == 255
    beat = hb.decode(cantools_frame("Heartbeat", {"State": 0, "LoadSeq": 3, "Cycle": 42,
                                                  "Overruns": 1}, 2).data)
    assert (beat.state, beat.load_seq, beat.cycle, beat.overruns) == ("running", 3, 42, 1)
    with pytest.raises(EncodeError, match="valid are running, holding"):
        hb.encode("dancing", 0, 0, 0, 0)
