"""``[estimate] initial_payload``: the service starts from a payload file (issue 16)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from deploy.config import ConfigError, load_config
from deploy.model.setup import INITIAL_STD, start_from_file
from deploy.writeback.checks import model_doubt
from deploy.writeback.settings import GateConfig
from iem.physics import PhysicsInformedEnsemble
from iem.types import PayloadEstimate
from sim.arm import NOMINAL_DYNAMICS
from sim.family import test_payloads
from sim.payload import PayloadError, load_payload, load_payload_prior, save_payload

TRUTH = test_payloads()["test-3w"]


def test_payload_files_carry_an_optional_phi_std(tmp_path):
    from sim.payload import payload_to_toml

    path = tmp_path / "tool.toml"
    std = np.linspace(1e-4, 1e-3, 10)
    path.write_text(payload_to_toml(TRUTH, phi_std=std), encoding="utf-8")
    payload, got = load_payload_prior(path)
    np.testing.assert_allclose(got, std)
    assert load_payload(path) == payload
    save_payload(TRUTH, path)
    assert load_payload_prior(path)[1] is None
    path.write_text(payload_to_toml(TRUTH, phi_std=-std), encoding="utf-8")
    with pytest.raises(PayloadError, match="phi_std"):
        load_payload(path)


def test_the_key_is_a_path_relative_to_the_cell_toml(tmp_path):
    cell = tmp_path / "etc" / "cell.toml"
    cell.parent.mkdir()
    cell.write_text('[estimate]\ninitial_payload = "tool.toml"\n', encoding="utf-8")
    assert load_config(cell).estimate.initial_payload == str(cell.parent / "tool.toml")


def test_the_model_starts_from_the_file(tmp_path):
    path = tmp_path / "tool.toml"
    save_payload(TRUTH, path)
    model = PhysicsInformedEnsemble(dynamics=NOMINAL_DYNAMICS)
    start_from_file(model, str(path))
    est = model.predict_one(np.zeros(21), None)
    np.testing.assert_allclose(est.phi, TRUTH.to_phi(), atol=1e-9)
    assert est.std[0] == pytest.approx(INITIAL_STD[0], rel=0.05)
    assert model_doubt(est, GateConfig())[0] == "unverified"


def test_a_model_without_a_payload_state_is_refused(tmp_path):
    from iem.ensemble import IncrementalEnsemble

    path = tmp_path / "tool.toml"
    save_payload(TRUTH, path)
    with pytest.raises(ConfigError, match=r"initial_payload.*IEM\+phys"):
        start_from_file(IncrementalEnsemble(), str(path))


def test_the_gate_waits_for_live_data():
    est = PayloadEstimate(t=0.0, phi=TRUTH.to_phi(), std=np.full(10, 1e-4), nis=math.nan,
                          ood=False, unverified=True)
    assert model_doubt(est, GateConfig())[0] == "unverified"
    checked = PayloadEstimate(t=0.0, phi=TRUTH.to_phi(), std=np.full(10, 1e-4), nis=1.0,
                              ood=False)
    assert model_doubt(checked, GateConfig()) is None


def test_the_gate_does_not_write_an_iem_estimate_out_of_its_distribution():
    allow = GateConfig(allow_without_uncertainty=True)  # the IEM reports no uncertainty
    est = PayloadEstimate(t=0.0, phi=TRUTH.to_phi(), ood=True, extra={"ood_score": 9.0})
    reason, detail = model_doubt(est, allow)
    assert reason == "out_of_distribution" and "9" in detail
    fine = PayloadEstimate(t=0.0, phi=TRUTH.to_phi(), ood=False, extra={"ood_score": 1.0})
    assert model_doubt(fine, allow) is None
    assert model_doubt(fine, GateConfig())[0] == "unreported"  # by default: held back
