"""The ``franka`` link through the real binding (pylibfranka 0.21.3) against franky-sim's FR3,
which serves the libfranka protocol on a loopback address (:class:`deploy.simcell.FciSim`).

What the fake (``franka_fake``) stands in for is only what this robot does not do on its
own: a ``set_load`` that hangs, the exclusive FCI's ``InvalidOperationException``, a
foreign exception class. Reading, writing, reading the load back, the refusal while the arm
moves and a lost network are franky-sim's own (the scene adds the refusal a real FR3 makes
and stops its state stream for the loss).
"""

from __future__ import annotations

import time

import numpy as np
import pytest

pytest.importorskip("pylibfranka", reason="the franka extra (pylibfranka) is not installed")
pytest.importorskip("franky_sim", reason="franky-sim is not installed")

from firmware_bridge.errors import ControllerSilent
from firmware_bridge.links import open_link
from sim.payload import load_payload
from tests.fci import STALL_RERUN

pytestmark = STALL_RERUN

REL = 1e-6
"""The robot state carries single-precision floats: a load reads back to 7 digits."""


@pytest.fixture(scope="module")
def scene():
    from deploy.simcell import FciSim

    with FciSim() as s:
        yield s


@pytest.fixture
def link(scene):
    link = open_link("franka", scene.host, silence_timeout=0.5)
    link.read(5.0)  # connected: the robot's states arrive
    yield link
    link.close()


@pytest.fixture
def payload():
    from pathlib import Path

    import sim

    return load_payload(Path(sim.__file__).parent / "payloads" / "test-3w.toml")


def test_states_come_from_the_robot_on_its_own_clock(link, scene):
    states = [link.read(1.0) for _ in range(300)]
    t = np.array([s.t for s in states])
    assert np.all(np.diff(t) > 0) and np.median(np.diff(t)) == pytest.approx(1e-3)
    assert abs(t[-1] - scene.status()["t"]) < 0.5  # the robot's time, not the connection's
    q = np.array(scene.status()["q"])
    np.testing.assert_allclose(states[-1].q, q, atol=1e-3)
    assert np.isfinite([s.tau_J for s in states]).all()


def test_set_load_reads_back_as_written_and_clear_empties(link, scene, payload):
    ack = link.wait_ack(link.send(payload), 3.0)
    assert ack.applied and ack.error == ""
    assert ack.load.mass == pytest.approx(payload.mass, rel=REL)
    np.testing.assert_allclose(ack.load.com, payload.com, rtol=REL, atol=1e-9)
    np.testing.assert_allclose(ack.load.inertia, payload.inertia, rtol=1e-5, atol=1e-9)
    assert scene.status()["m_load"] == pytest.approx(payload.mass)
    report = link.load_report
    assert report.has_values and report.load.mass == pytest.approx(payload.mass, rel=REL)
    ack = link.wait_ack(link.send(None), 3.0)
    assert ack.applied and ack.load is None and scene.status()["m_load"] == 0.0


def test_set_load_is_refused_while_the_arm_moves(link, scene, payload):
    from sim.paths import linear_path
    from sim.robot import ArmModel

    q0 = np.array(scene.status()["q"])
    scene.play(linear_path(q0, q0 + 0.1, 1.5, model=ArmModel(description="fr3")).q)
    # ten in a row, each answered while the arm still moves: the robot process's command
    # thread gets its turn between two states (with the child's lock handed over only every
    # 5 ms, a call waited 130-200 ms at the median and some landed after the motion)
    for _ in range(10):
        ack = link.wait_ack(link.send(payload), 3.0)
        assert not ack.applied and "command not possible in the current mode" in ack.error
        assert ack.load is None  # the load a state read after the refusal reports
    scene.wait_still()
    scene.play(linear_path(q0 + 0.1, q0, 1.5, model=ArmModel(description="fr3")).q)
    scene.wait_still()
    ack = link.wait_ack(link.send(payload), 3.0)
    assert ack.applied
    link.wait_ack(link.send(None), 3.0)


def pass_along(link, scene, path) -> tuple[np.ndarray, np.ndarray]:
    """``(t since the motion began, tau_J)`` of the states the link read while the robot's
    program played ``path`` (joint positions at 1 kHz)."""
    def ends():
        return [t for t, kind, _ in scene.events() if kind == "motion_end"]

    before = len(ends())
    scene.play(path)
    states = []
    while True:
        state = link.read(1.0)
        states.append(state)
        done = ends()[before:] if len(states) % 200 == 0 else []
        if done and state.t > done[0]:
            break
    begun = [t for t, kind, _ in scene.events() if kind == "motion_start"][-1]
    t = np.array([s.t for s in states]) - begun
    return t, np.array([s.tau_J for s in states])


def test_the_payloads_weight_reaches_tau_J_and_set_load_changes_only_the_model(
        link, scene, payload):
    """The same motion bare and loaded: the joint torques differ by the payload's own
    (its regressor times its parameters), friction, armature and damping being the same at
    the same speeds; with setLoad the torques stay what the physics needs (the controller's
    model changes, and ``m_load``), while the tracking error shrinks."""
    from sim.paths import linear_path
    from sim.robot import ArmModel

    kinematics = ArmModel(description="fr3")
    q0 = np.array(scene.status()["q"])
    q1 = q0 + np.array([0.5, 0.3, 0.0, 0.3, 0.0, -0.3, 0.0])
    there = linear_path(q0, q1, 2.0, model=kinematics)
    back = linear_path(q1, q0, 2.0, model=kinematics).q

    def run(mount=None, set_load=None):
        if mount is not None:
            scene.mount(mount)
        if set_load is not None:
            ack = link.wait_ack(link.send(set_load), 3.0)
            assert ack.applied, ack.error
        t, tau = pass_along(link, scene, there.q)
        pass_along(link, scene, back)
        scene.unmount()
        link.wait_ack(link.send(None), 3.0)
        # on one grid of the motion's time (a state the link lost leaves no hole)
        return np.column_stack([np.interp(grid, t, tau[:, j]) for j in range(7)])

    grid = np.arange(0.4, 1.6, 1e-3)  # moving: every joint's friction at its sliding value
    bare = run()
    loaded = run(mount=payload)
    modelled = run(mount=payload, set_load=payload)
    k = np.round(grid * 1e3).astype(int)
    expected = np.array([kinematics.payload_regressor(there.q[i], there.dq[i], there.ddq[i])
                         @ payload.to_phi() for i in k])
    assert np.abs(expected).mean(axis=0).max() > 5.0  # a load worth seeing on this path
    np.testing.assert_allclose((loaded - bare).mean(axis=0), expected.mean(axis=0), atol=0.25)
    np.testing.assert_allclose(modelled.mean(axis=0), loaded.mean(axis=0), atol=0.1)


def test_a_lost_network_is_a_silence_and_the_link_connects_again(link, scene):
    """franky-sim stops its state stream for 3 s of the wall clock: libfranka's UDP receive
    times out (its Robot is unusable after that), the link reports the silence and connects
    anew."""
    link.read(1.0)
    scene.pause(3.0)
    deadline = time.monotonic() + 20.0
    with pytest.raises(ControllerSilent):  # once the states read before the pause are taken
        while time.monotonic() < deadline:
            link.read(0.3)
    while True:
        try:
            state = link.read(0.5)
            break
        except ControllerSilent:
            assert time.monotonic() < deadline, "the link did not come back"
    assert link.reconnects >= 1 and np.isfinite(state.tau_J).all()


def test_reading_states_never_stops_the_other_threads(link, scene):
    """pylibfranka's ``read_once`` waits for the next state without releasing Python's
    interpreter lock: read in this process, the link's reader thread would hold the lock for
    libfranka's whole 1 s receive timeout while the states stop, and every other thread (the
    estimator) with it. The link reads in a process of its own, so this thread keeps running
    through a 2 s loss of the network: the longest gap between two of its loop turns stays
    far below that second (the turns take microseconds; 0.5 s leaves room for a busy
    machine)."""
    import contextlib
    import threading

    stop = threading.Event()

    def consume():
        while not stop.is_set():
            with contextlib.suppress(ControllerSilent):
                link.read(0.3)

    reader = threading.Thread(target=consume, daemon=True)
    reader.start()
    try:
        scene.pause(2.0)
        last, longest, end = time.perf_counter(), 0.0, time.perf_counter() + 2.5
        while (now := time.perf_counter()) < end:
            longest, last = max(longest, now - last), now
        assert longest < 0.5, f"this thread stood still {longest:.2f} s while states stopped"
    finally:
        stop.set()
        reader.join(2.0)


def test_the_robot_process_ends_with_the_process_that_started_it(scene):
    """pylibfranka's child process (:class:`firmware_bridge.franka_process.RobotProcess`)
    ends when the program that started it is killed, rather than holding the FCI, which the
    robot gives one client at a time."""
    from tests.orphans import assert_child_ends_with_its_program

    assert_child_ends_with_its_program(
        "import sys, time, pylibfranka\n"
        "from firmware_bridge.franka_process import RobotProcess\n"
        f"robot = RobotProcess({scene.host!r}, pylibfranka)\n"
        "robot.read_once()\n"  # running, reading states
        "print(robot.pid, flush=True)\n"
        "time.sleep(60)\n")


def test_the_scene_holds_the_payload_where_its_file_puts_it(scene, payload):
    """The weight of a payload mounted in the scene pulls at the CoM its file gives, in the
    flange frame: the joint torque holding it, by MuJoCo's Jacobian of the payload body's
    CoM, is Pinocchio's payload regressor of the FR3 times the payload's parameters, at two
    poses. A CoM left at the flange's origin (MuJoCo's ``body_sameframe`` of a body compiled
    with its inertial frame there) is 0.3-0.7 N·m off on joints 5-6 of test-3w's 64 mm;
    1e-3 N·m is a CoM within about a tenth of a millimetre."""
    from sim.description import arm_description
    from sim.paths import linear_path
    from sim.robot import ArmModel

    kinematics = ArmModel(description="fr3")
    task = arm_description("fr3").task
    checked = 0
    for pose in task:
        scene.play(linear_path(np.array(scene.status()["q"]), np.array(pose), 3.0,
                               model=kinematics).q)
        scene.wait_still()
        scene.mount(payload)
        mount = [e for e in scene.events() if e[1] == "mount"][-1][2]
        scene.unmount()
        q = np.array(mount["q"])
        expected = kinematics.payload_regressor(q, np.zeros(7), np.zeros(7)) @ payload.to_phi()
        np.testing.assert_allclose(mount["gravity_torque"], expected, atol=1e-3)
        checked += 1
    assert checked == 2
