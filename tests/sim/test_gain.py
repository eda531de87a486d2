"""The torque sensors' gain: an arm file holds it, the arm model reads a payload's torque
through it, a known load measures it (``iem calibrate --known-load``), and ``iem identify
--arm`` uses it. The truth is Pinocchio's RNEA of an arm whose sensors read a payload's
torque ``(1 + g)`` times (``ArmModel.rnea_with_payload``), against which the regressor is
checked first."""

from dataclasses import replace

import numpy as np
import pytest

from deploy.cli import main
from iem.errors import InvalidInputError
from sim.arm import ArmParams, load_arm
from sim.calibration.gain import fit_gain
from sim.family import test_payloads
from sim.identify import identify
from sim.paths import calibration_path, excitation_path
from sim.payload import save_payload
from sim.robot import ArmModel
from tests.firmware_bridge.test_recordings import write_csv

GAIN = np.array([0.012, -0.018, 0.015, 0.021, -0.009, 0.006, 0.02])
ARM = ArmParams.nominal()
KNOWN = test_payloads()["test-3w"]


def recording(path, payload, gain=GAIN, noise=0.02, seed=0):
    """``(t, q, dq, tau)`` of ``path`` with ``payload`` on an arm whose sensors have ``gain``,
    plus white torque noise (N·m)."""
    model = ArmModel(arm=replace(ARM, gain=gain))
    phi = payload.to_phi()
    tau = np.array([model.rnea_with_payload(path.q[k], path.dq[k], path.ddq[k], phi)
                    for k in range(len(path))])
    tau += np.random.default_rng(seed).normal(0.0, noise, tau.shape)
    return path.t, path.q, path.dq, tau


def test_an_arm_keeps_its_gain_and_an_arm_without_one_its_state():
    assert "gain" not in ARM.to_state()  # the CRC model files record stays
    with_gain = replace(ARM, gain=GAIN)
    assert with_gain.crc32 != ARM.crc32
    back = ArmParams.from_state(with_gain.to_state())
    assert np.array_equal(back.gain, GAIN) and back.crc32 == with_gain.crc32
    for bad in ([0.5] * 7, [np.nan] * 7, [0.0] * 6):
        with pytest.raises(InvalidInputError, match="gain"):
            replace(ARM, gain=bad)


def test_the_arm_model_reads_a_payloads_torque_through_the_gain():
    plain, gained = ArmModel(arm=ARM), ArmModel(arm=replace(ARM, gain=GAIN))
    phi = test_payloads()["test-2w"].to_phi()
    rng = np.random.default_rng(3)
    for _ in range(5):
        q, dq, ddq = plain.random_state(rng)
        tau, Y = plain.rnea_and_regressor(q, dq, ddq)
        tau_g, Y_g = gained.rnea_and_regressor(q, dq, ddq)
        assert np.array_equal(tau, tau_g)  # the bare arm: what its sensors read already
        truth = gained.rnea_with_payload(q, dq, ddq, phi) - tau  # RNEA with the payload
        assert np.allclose(Y_g @ phi, truth, rtol=1e-9, atol=1e-9)
        assert np.allclose(Y @ phi * (1 + GAIN), truth, rtol=1e-9, atol=1e-9)
        assert np.allclose(gained.payload_mass_matrix(q, phi),
                           plain.payload_mass_matrix(q, phi) * (1 + GAIN)[:, None])


def test_a_known_load_measures_the_gain_of_the_joints_it_turns():
    gain, report = fit_gain(ARM, [recording(calibration_path(), KNOWN)], KNOWN)
    turned = [j for j in range(7) if j + 1 not in report["unmeasured"]]
    assert {2, 3, 4} <= {j + 1 for j in turned}  # the joints that carry its weight
    assert np.allclose(gain[turned], GAIN[turned], atol=1e-3)
    assert not gain[[j - 1 for j in report["unmeasured"]]].any()  # none guessed
    assert report["payload"] == KNOWN.name


def test_identify_with_the_gain_gets_a_heavy_tools_mass():
    tool = test_payloads()["test-4w"]  # 1.89 kg, not the known load
    gain, _ = fit_gain(ARM, [recording(calibration_path(), KNOWN)], KNOWN)
    loaded = recording(excitation_path(), tool, seed=1)
    without = identify(loaded, arm=ARM, check_excitation=False)
    with_gain = identify(loaded, arm=replace(ARM, gain=gain), check_excitation=False)
    assert abs(without.phi[0] - tool.mass) > 0.01  # about the gain of the shoulder joints
    assert abs(with_gain.phi[0] - tool.mass) < 0.003


def test_a_load_that_turns_no_joint_reads_no_gain():
    feather = replace(KNOWN, mass=0.001,
                      inertia=np.asarray(KNOWN.inertia) * 0.001 / KNOWN.mass)
    with pytest.raises(InvalidInputError, match="turns no joint"):
        fit_gain(ARM, [recording(calibration_path(), feather)], feather)


def test_iem_calibrate_writes_the_gain_a_known_load_reads(tmp_path, monkeypatch, capsys):
    """The command's path from its options to the arm file (the bare fit itself is tested
    in test_calibration: here it returns the nominal arm)."""
    import deploy.commands.calibrate as cal

    fitted = replace(ARM, report={"source": "bare.csv", "duration_s": 30.0, "segments": 1,
                                  "base_parameters": 43, "condition_number": 1000.0,
                                  "rms_before": [0.1] * 7, "rms_after": [0.01] * 7,
                                  "consistency_moved_bodies": [], "warnings": []})
    monkeypatch.setattr(cal, "calibrate_sources", lambda *a, **k: fitted)
    every = slice(None, None, 5)  # 200 Hz: a small file
    t, q, dq, tau = recording(calibration_path(), KNOWN)
    write_csv(tmp_path / "loaded.csv", t[every], q[every], dq[every], tau[every])
    save_payload(KNOWN, tmp_path / "known.toml")
    (tmp_path / "bare.csv").write_text("unused")
    out = tmp_path / "arm.msgpack"
    assert main(["calibrate", str(tmp_path / "bare.csv"), "--known-load",
                 str(tmp_path / "loaded.csv"), "--known-payload", str(tmp_path / "known.toml"),
                 "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "torque sensors' gain, read with the known load" in printed
    arm = load_arm(out)
    assert np.allclose(arm.gain[1:4], GAIN[1:4], atol=2e-3)
    assert arm.report["gain"]["payload"] == KNOWN.name
    assert main(["calibrate", str(tmp_path / "bare.csv"), "--known-load",
                 str(tmp_path / "loaded.csv"), "--out", str(out)]) == 2
    assert "--known-payload TOML go together" in capsys.readouterr().err
    assert main(["calibrate", "--write-motion", str(tmp_path / "m.csv"), "--known-load",
                 str(tmp_path / "loaded.csv")]) == 2
    assert "--known-load has no effect with --write-motion" in capsys.readouterr().err
