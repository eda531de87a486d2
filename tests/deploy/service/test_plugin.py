"""The plug-in inside a user's program (:class:`deploy.service.PayloadPlugin`, the ``program``
link): the same service as ``iem run``, fed from a motion's callback, writing with the
program's robot between motions; and the program of docs/deploying.md run against
franky-sim's FR3 through franky-control."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.fci import STALL_RERUN
from tests.franky_state import RobotState as State

from ..conftest import REPO, model_kind, write_toml


class Robot:
    """A program's robot over the simulated FR3 plant: ``set_load`` changes what its states
    report (its controller's model), never the plant."""

    def __init__(self, payload) -> None:
        from sim.plant import ArmPlant

        self.plant = ArmPlant(payload=payload, description="fr3")
        self.load = (0.0, [0.0] * 3, [0.0] * 9)
        self.calls = []
        self.last = None

    def set_load(self, mass, com, inertia) -> None:
        self.calls.append(float(mass))
        self.load = (float(mass), list(com), list(inertia))


def program_config(tmp_path, model_file, estimate=None, **gate) -> Path:
    model = tmp_path / "model.msgpack"
    shutil.copyfile(model_file, model)
    return write_toml(tmp_path / "cell.toml", {
        "link": {"kind": "program"},
        "model": {"path": str(model), "train_if_missing": False,
                  "kind": model_kind(model_file)},
        "estimate": estimate or {}, "gate": gate, "log": {"status_line": "off"}})


def test_the_plugin_estimates_from_fed_states_and_writes_between_motions(
        trained_fr3_model_file, tmp_path):
    """Motions of the simulated FR3 carrying a payload: every state fed as a callback would,
    ``apply()`` between motions. A write the gate decides during a motion is refused at once
    (the robot takes none then) and kept; ``apply()`` writes it with the robot's
    ``set_load`` and acknowledges it with the load the robot's state reads back."""
    from deploy.service import PayloadPlugin
    from firmware_bridge.program_link import MOVING
    from sim.family import default_test_payload
    from sim.paths import excitation_path
    from sim.robot import ArmModel

    payload = default_test_payload()
    robot = Robot(payload)
    path = excitation_path(20.0, model=ArmModel(description="fr3"))
    robot.plant.reset(path.q[0])
    # states fed faster than the robot's clock: learn from every point all the same
    config = program_config(tmp_path, trained_fr3_model_file, estimate={"max_lag_s": 0.0},
                            allow_without_uncertainty=True)
    plugin = PayloadPlugin(robot, str(config), read_state=lambda r: State(r.last, r.load))
    acks = []
    try:
        for start in range(0, len(path.t) - 1, 4000):  # five motions of 4 s
            for k in range(start, min(start + 4000, len(path.t))):
                robot.last = robot.plant.step(path.q[k], path.dq[k], path.ddq[k])
                plugin.callback(State(robot.last, robot.load), None, None, None, None)
            deadline = time.monotonic() + 60.0  # the service catches up with the motion
            while plugin.reading().t is None or plugin.reading().t < robot.last.t - 0.1:
                assert time.monotonic() < deadline, (plugin.reading().t, robot.last.t)
                time.sleep(0.01)
            acks.append(plugin.apply())
        reading = plugin.reading()
    finally:
        summary = plugin.close()
    written = [a for a in acks if a is not None and a.applied]
    assert written, (acks, summary["gate"])
    assert robot.calls and robot.load[0] == written[-1].load.mass  # read back after it
    assert summary["writes"]["refused_by_controller"] >= 1  # decided while moving
    assert summary["cycles"] > 1000 and summary["load_in_force_confirmed"]
    assert reading.payload is not None and reading.mass_band_kg is None  # IEM: no band
    assert reading.verdict["reason"] and MOVING.startswith("the arm is moving")


def test_the_service_runs_outside_the_programs_process_and_the_callback_never_waits(
        trained_fr3_model_file, tmp_path):
    """The program's process gets one thread of the plug-in's, the writer that hands the fed
    states over (the estimating holds another process's interpreter lock); with the
    service's process stopped, every callback still returns: what neither the pipe nor the
    writer's queue can hold is dropped and counted, and the service goes on when it
    resumes."""
    import os
    import signal
    import threading

    from deploy.service import PayloadPlugin
    from sim.family import default_test_payload
    from sim.paths import excitation_path
    from sim.robot import ArmModel

    robot = Robot(default_test_payload())
    path = excitation_path(12.0, model=ArmModel(description="fr3"))
    robot.plant.reset(path.q[0])
    config = program_config(tmp_path, trained_fr3_model_file, allow_without_uncertainty=True)
    threads = set(threading.enumerate())
    plugin = PayloadPlugin(robot, str(config), read_state=lambda r: State(r.last, r.load))
    try:
        assert [t.name for t in set(threading.enumerate()) - threads] == ["iem-plugin-writer"]
        assert plugin._child.pid != os.getpid() and plugin._child.poll() is None
        os.kill(plugin._child.pid, signal.SIGSTOP)
        try:
            for k in range(len(path.t)):
                robot.last = robot.plant.step(path.q[k], path.dq[k], path.ddq[k])
                plugin.callback(State(robot.last, robot.load), None, None, None, None)
        finally:
            os.kill(plugin._child.pid, signal.SIGCONT)
        assert plugin.dropped > 0
        deadline = time.monotonic() + 60.0
        while plugin.reading().t is None:
            assert time.monotonic() < deadline
            time.sleep(0.01)
    finally:
        summary = plugin.close()
    assert summary["cycles"] > 0 and plugin.written + plugin.dropped == len(path.t)


def test_the_service_process_ends_with_the_program(trained_fr3_model_file, tmp_path):
    """A program killed outright takes the plug-in's process with it."""
    from tests.orphans import assert_child_ends_with_its_program

    config = program_config(tmp_path, trained_fr3_model_file)
    assert_child_ends_with_its_program(
        "import sys, time\n"
        "from deploy.service import PayloadPlugin\n"
        f"plugin = PayloadPlugin(object(), {str(config)!r}, read_state=lambda r: None)\n"
        "print(plugin._child.pid, flush=True)\n"
        "time.sleep(60)\n", cwd=REPO)


def test_a_config_of_another_link_kind_is_refused(trained_fr3_model_file, tmp_path):
    from deploy.config import ConfigError
    from deploy.service import PayloadPlugin

    config = write_toml(tmp_path / "cell.toml", {"link": {"kind": "virtual"}})
    with pytest.raises(ConfigError, match='needs kind = "program"'):
        PayloadPlugin(object(), str(config), read_state=lambda r: None)


def test_a_robot_of_an_unknown_library_needs_read_state(trained_fr3_model_file, tmp_path):
    from deploy.service import PayloadPlugin

    config = program_config(tmp_path, trained_fr3_model_file)
    with pytest.raises(TypeError, match=r"franky\.Robot or a pylibfranka\.Robot"):
        PayloadPlugin(object(), str(config))


def example_program() -> str:
    """The program docs/deploying.md shows (its first Python block after the heading)."""
    text = (REPO / "docs" / "deploying.md").read_text(encoding="utf-8")
    section = text[text.index("## The plug-in inside your own program"):]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


@STALL_RERUN
def test_the_docs_example_runs_against_franky_sim(trained_fr3_phys_model_file, tmp_path):
    """The documented franky-control program, as written, against franky-sim's FR3: its
    hand picks a payload up (the scene mounts it when the hand closes), its motions feed
    the plug-in, ``apply()`` runs between them, and it ends with the service's summary."""
    from importlib.util import find_spec

    if find_spec("franky") is None:  # never imported here: this process may hold pylibfranka
        pytest.skip("the franky extra (franky-control) is not installed")
    pytest.importorskip("franky_sim", reason="franky-sim is not installed")
    from deploy.simcell import FciSim
    from sim.family import default_test_payload

    program = example_program()
    assert len(program.splitlines()) <= 40
    script = tmp_path / "pick_and_place.py"
    script.write_text(program)
    config = program_config(tmp_path, trained_fr3_phys_model_file)
    with FciSim() as scene:
        scene.grasp_queue([default_test_payload()])
        run = subprocess.run([sys.executable, str(script), scene.host, str(config)],
                             cwd=REPO, capture_output=True, text=True, timeout=600)
        events = scene.events()
    assert run.returncode == 0, run.stderr[-2000:]
    lines = run.stdout.splitlines()
    assert sum(line.startswith("estimate ") for line in lines) == 3, run.stdout
    assert lines[-1].startswith("writes: {")
    kinds = [kind for _, kind, _ in events]
    assert kinds.count("mount") == 1 and kinds.count("unmount") == 1
    assert kinds.count("motion_end") == 3  # the program's three motions
