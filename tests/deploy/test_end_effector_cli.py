"""The end effector and the arm's noise through the commands: calibrate, train, the config,
and the watch that names a wrong arm model."""

import logging

import numpy as np
import pytest

from deploy.cli import main
from deploy.config import ConfigError, config_from_dict
from deploy.service.arm_watch import HOLD_S, ArmWatch
from iem.types import PayloadEstimate
from sim.arm import ArmParams, load_arm, save_arm


def test_config_declares_the_end_effector_and_the_noise(tmp_path):
    cfg = config_from_dict({})
    assert cfg.arm.end_effector == "franka_hand" and cfg.arm.noise == "auto"
    assert config_from_dict({"arm": {"end_effector": "none"}}).arm.end_effector == "none"
    with pytest.raises(ConfigError, match=r"end_effector = 'robotiq' is not valid.*franka_hand"):
        config_from_dict({"arm": {"end_effector": "robotiq"}})
    with pytest.raises(ConfigError, match=r"noise = 'white' is not valid.*'auto', 'arm', 'sensor'"):
        config_from_dict({"arm": {"noise": "white"}})


def test_train_refuses_an_arm_file_of_another_end_effector_naming_both(tmp_path, capsys):
    arm = tmp_path / "arm.msgpack"
    save_arm(ArmParams.nominal("none"), arm)
    assert main(["train", "--kind", "IEM+phys", "--arm", str(arm), "--end-effector",
                 "franka_hand", "--out", str(tmp_path / "m.msgpack")]) == 2
    err = capsys.readouterr().err
    assert "end effector mismatch" in err and "'none'" in err and "'franka_hand'" in err
    assert not (tmp_path / "m.msgpack").exists()


def test_calibrate_records_the_end_effector_and_the_noise(tmp_path, capsys):
    """A bare simulated arm without its hand, recorded as a joint-state CSV: the arm file
    says 'none' and carries the noise measured on traffic the fit did not see."""
    from deploy.bench.real import write_csv
    from sim.paths import calibration_path
    from sim.plant import ArmPlant, RealityGap

    gap = RealityGap(seed=5)
    roll = ArmPlant(payload=None, seed=3, gap=gap).follow(calibration_path(16.0, seed=1))
    rec = tmp_path / "bare.csv"
    write_csv(rec, roll.t, roll.q, roll.dq, roll.tau)
    out = tmp_path / "arm.msgpack"
    assert main(["calibrate", str(rec), "--out", str(out), "--end-effector", "none"]) == 0
    text = capsys.readouterr().out
    assert "end effector: none" in text and "reads as a payload of" in text
    arm = load_arm(out)
    assert arm.end_effector == "none" and arm.noise is not None
    # the realistic plant's leftover is the arm's, above the sensor's 0.01-0.02 N·m
    assert min(arm.noise["std"]) > 0.01 and max(arm.noise["std"]) < 1.0
    assert all(w >= 11.0 for w in arm.noise["weight"])


def _est(t, mass, std=0.01):
    phi = np.zeros(10)
    phi[0] = mass
    return phi, PayloadEstimate(t=t, phi=phi, std=np.full(10, std), nis=1.0, ood=False)


def test_the_watch_names_a_mass_that_stays_clearly_negative(caplog):
    watch = ArmWatch()
    for k in range(int(2 * HOLD_S / 0.01)):  # a mass below zero, but within its band
        watch.observe(k * 0.01, *_est(k * 0.01, -0.03, std=0.02))
    assert watch.finding is None
    for k in range(int(0.5 * HOLD_S / 0.01)):  # clearly negative, not yet for long
        watch.observe(10 + k * 0.01, *_est(10 + k * 0.01, -0.7))
    watch.observe(20.0, *_est(20.0, 0.1))  # back above: the clock starts again
    assert watch.finding is None
    with caplog.at_level(logging.WARNING, logger="iem.service"):
        for k in range(int(1.2 * HOLD_S / 0.01)):
            watch.observe(30 + k * 0.01, *_est(30 + k * 0.01, -0.7))
    assert watch.finding is not None and watch.finding["mass_kg"] == pytest.approx(-0.7)
    assert "end effector" in watch.finding["message"]
    assert sum("arm model does not match" in r.message for r in caplog.records) == 1
