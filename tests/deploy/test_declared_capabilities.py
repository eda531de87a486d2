"""What a cell needs of its model and its link is declared, and refused at start when it is
missing: the model's kind and point rate (:class:`iem.base.Estimator`), the link's payload
sink and wire profile (:mod:`firmware_bridge.links`)."""

from __future__ import annotations

import pytest

from deploy.config import ConfigError, config_from_dict
from deploy.model.setup import load_or_train_model
from deploy.model.training import check_model_arm
from deploy.service.capabilities import check_sink, wire_check_for
from deploy.writeback.gate import SafetyGate
from deploy.writeback.wire import wire_check_of
from deploy.writeback.writer import LoadWriter
from firmware_bridge.links import EstimatePublisher, PayloadSink, WireProfiled
from firmware_bridge.load_range import FLOAT64, of_profile
from firmware_bridge.protocol import profile as wire_profile
from iem.base import BaseEstimator
from iem.ensemble import IncrementalEnsemble
from iem.errors import ModelFileError
from iem.model_kinds import DEFAULT_MODEL
from iem.persistence import save_model
from iem.physics import PhysicsInformedEnsemble
from sim.arm import NOMINAL_DYNAMICS


def _config(path, **model) -> object:
    return config_from_dict({"model": {"path": str(path), "train_if_missing": False, **model},
                             "link": {"kind": "virtual", "profile": "fd"}})


def test_a_model_file_of_another_kind_than_the_configuration_is_refused(tmp_path):
    path = tmp_path / "model.msgpack"
    save_model(IncrementalEnsemble(seed=1), path)
    assert _config(path).model.kind == DEFAULT_MODEL == "IEM+phys"
    with pytest.raises(ConfigError) as info:
        load_or_train_model(_config(path))
    message = str(info.value)
    assert "holds a model of kind 'IEM'" in message and "kind is 'IEM+phys'" in message
    assert "set kind = 'IEM'" in message and "iem train --kind IEM+phys" in message
    assert load_or_train_model(_config(path, kind="IEM")).name == "IEM"


def test_the_point_rate_is_declared_and_checked(tmp_path):
    """IEM+phys declares the point rate its filters were made for and is refused at
    another; the IEM declares none (None) and runs at any rate."""
    assert IncrementalEnsemble().rate_hz is None
    path = tmp_path / "phys.msgpack"
    save_model(PhysicsInformedEnsemble(dynamics=NOMINAL_DYNAMICS, rate_hz=50.0), path)
    with pytest.raises(ConfigError, match=r"made for 50 block points per second.*100"):
        load_or_train_model(_config(path))
    save_model(PhysicsInformedEnsemble(dynamics=NOMINAL_DYNAMICS, rate_hz=100.0), path)
    assert load_or_train_model(_config(path)).rate_hz == 100.0
    save_model(IncrementalEnsemble(seed=1), path)
    config = config_from_dict({"model": {"path": str(path), "kind": "IEM",
                                         "train_if_missing": False},
                               "link": {"kind": "virtual", "profile": "classic"},
                               "estimate": {"block_frames": 4}})
    assert load_or_train_model(config).name == "IEM"


class _Specs(BaseEstimator):
    """A model whose hyper-parameters reference an arm by content."""

    name = "specs"

    def __init__(self, reversal: str) -> None:
        self.reversal = reversal

    def params(self) -> dict:
        return {"ensemble": {"reversal": self.reversal}}


def test_an_arm_referenced_in_the_hyper_parameters_must_be_the_trained_one():
    spec = "sim.coverage:reversed_velocities@arm:0000abcd"
    with pytest.raises(ModelFileError, match=r"ensemble\.reversal.*0x0000abcd"):
        check_model_arm(_Specs(spec), None)
    model = _Specs(spec)
    model.trained_arm = {"crc32": 0xABCD, "source": "arm.msgpack"}
    check_model_arm(model, {"crc32": 0xABCD, "source": "arm.msgpack"})  # the same arm
    check_model_arm(_Specs("sim.coverage:reversed_velocities"), None)  # references none


class _Sink:
    """Every member of :class:`PayloadSink`."""

    last_ack = None
    load_report = None

    def send(self, payload) -> int:
        return 1

    def wait_ack(self, seq, timeout=1.0):
        return None

    def close(self) -> None:
        pass


_NoReport = type("_NoReport", (), {k: v for k, v in vars(_Sink).items()
                                   if k not in ("load_report", "__dict__", "__weakref__")})
"""A sink of an older seam: every member of :class:`PayloadSink` but ``load_report``."""


def test_a_writer_needs_a_payload_sink_and_refuses_anything_else():
    gate = SafetyGate()
    assert isinstance(_Sink(), PayloadSink) and not isinstance(_NoReport(), PayloadSink)
    check_sink(_Sink(), write=True)
    assert LoadWriter(gate, _Sink(), write=True).sink is not None
    with pytest.raises(ConfigError, match=r"_NoReport cannot write loads.*PayloadSink"):
        check_sink(_NoReport(), write=True)
    check_sink(_NoReport(), write=False)
    assert LoadWriter(gate, _NoReport(), write=False).sink is None  # decides only


class _Profiled:
    profile = wire_profile("classic")


def test_a_can_kind_needs_a_declared_wire_profile():
    assert isinstance(_Profiled(), WireProfiled) and not isinstance(_Sink(), WireProfiled)
    check = wire_check_for(_Profiled(), "virtual")
    assert check is not None and check.__self__ == of_profile("classic")
    assert wire_check_of(_Profiled()).__self__ == of_profile("classic")
    with pytest.raises(ConfigError, match=r"kind 'socketcan'.*_Sink declares no wire profile"):
        wire_check_for(_Sink(), "socketcan")
    assert wire_check_for(_Sink(), "serial").__self__ is FLOAT64  # msgpack floats
    assert wire_check_for(_Sink()) is None
    assert wire_check_of(_Sink()) is None


def test_the_estimate_topics_are_a_declared_protocol():
    from firmware_bridge.can_link import CanLink
    from firmware_bridge.ros2_link import Ros2Link

    assert issubclass(Ros2Link, EstimatePublisher)
    assert not issubclass(CanLink, EstimatePublisher)
