"""franky-sim's FR3 as the robot a libfranka client talks to, with a payload in its physics.

:class:`FciSim` runs franky-sim 1.0.4 (Apache-2.0; MuJoCo Menagerie's FR3 with the Franka
Hand, served over the libfranka network protocol) in a child process of its own, on a free
loopback address (``host``: 127.0.0.1, else the next free 127.0.0.x, which libfranka's fixed
ports allow), and controls it through a pipe. What it adds to franky-sim, each for what a
user of a real FR3 gets:

- **A payload in the physics.** A body fixed to the flange (libfranka's frame F, Menagerie's
  ``fr3_link7`` + 0.107 m) whose mass, CoM and inertia (from a payload file,
  :func:`sim.payload.load_payload`) are set while the simulation runs: :meth:`FciSim.mount`,
  :meth:`FciSim.unmount`, or with the gripper (:meth:`FciSim.grasp_queue`: the next payload
  is mounted when the hand closes, removed when it opens). Its weight reaches ``tau_J``
  through the physics; ``set_load`` changes only the controller's model and ``m_load``.
- **setLoad refused while the arm moves** (``refuse_while_moving``, default on): franky-sim
  applies a ``setLoad`` at any time; a real FR3 answers "command not possible in the current
  mode" while a motion runs (franka_ros #25), which libfranka raises as ``CommandException``.
- **The robot's own program.** :meth:`FciSim.play` moves the arm along a joint path at 1 kHz
  (franky-sim's joint position controller), as a program on the robot would while a
  plug-in reads it through the FCI; the robot reports ``robot_mode`` Move meanwhile. A
  libfranka motion of a client takes over at once.
- **The robot's clock.** A state's time counts from the robot's start, not from the client's
  connection (franky-sim numbers its states from each connection).
- **Stable joint damping.** franky-sim's default D gains (450/350/200 N·m·s/rad) exceed what
  its 1 ms step can damp on the light joints (``kv h / M_jj`` up to 2.6 on joint 7): their
  torque rings at 500 Hz (joint 7 at its ±12 N·m limit 66 % of the time, measured through
  franky-control). :data:`STABLE_KV` keeps ``kv h / min M_jj`` near 0.5 (Menagerie's
  joint inertia with armature, over the joint ranges); ``kv=None`` keeps franky-sim's.
- **Network loss.** :meth:`FciSim.pause` stops the state stream for a while (libfranka's
  UDP receive times out after 1 s).

Truth is logged in the robot's time (:meth:`FciSim.events`): payloads mounted (with the pose
and the joint torque that holds the payload's weight there, by MuJoCo's own Jacobian of its
CoM: :func:`holding_torque`) and removed, motions begun and ended (the robot's program's or
a client's), every ``setLoad`` applied (with the values) or refused, and the pose every
0.1 s.

Every scene takes an inter-process lock (:data:`LOCK_FILE` in the system's temporary
folder) for its life: two on one 2-core machine starve each other's 1 kHz loop. One that
finds the lock held waits up to ``lock_timeout`` s, then fails naming the holder.

franky-sim is imported only in the child process. Its internals that this module reaches
into (franky-sim 1.0.4, pinned in pyproject.toml) are checked when the child starts.
"""

from __future__ import annotations

import contextlib
import fcntl
import multiprocessing as mp
import os
import queue
import tempfile
import threading
import time
from pathlib import Path as FsPath

import numpy as np

FRANKY_SIM_VERSION = "1.0.4"
STABLE_KV = (150.0, 350.0, 140.0, 350.0, 50.0, 60.0, 38.0)
"""Joint D gains, N·m·s/rad: ``min(franky-sim's, 0.5 min M_jj / 1 ms)``, ``min M_jj``
(0.32 0.77 0.29 0.85 0.10 0.13 0.076 kg·m²) the least joint-space inertia of Menagerie's FR3
with the hand and armature over 3000 random poses in the joint ranges."""
GRASP_WIDTH_M = 0.03
"""The hand holds a grasped payload while its fingers are closer than this, m."""
POSE_PERIOD_S = 0.1
"""A pose is logged this often while the arm moves, s."""
LOCK_FILE = "iem-franky-sim.lock"
LOCK_TIMEOUT_S = 600.0
START_TIMEOUT_S = 60.0
CALL_TIMEOUT_S = 30.0
MOVING = "Move"


class FciSimError(RuntimeError):
    """The simulated robot did not start, answer or stop as asked (the reason in words)."""


# -- the lock --------------------------------------------------------------------------------
@contextlib.contextmanager
def scene_lock(timeout: float = LOCK_TIMEOUT_S):
    """Hold the machine's franky-sim lock (see the module docstring)."""
    path = FsPath(tempfile.gettempdir()) / LOCK_FILE
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
    deadline = time.monotonic() + timeout
    try:
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() >= deadline:
                    holder = os.pread(fd, 512, 0).decode(errors="replace").strip() or "unknown"
                    raise FciSimError(f"another franky-sim scene holds {path} for more than "
                                      f"{timeout:g} s (held by {holder}); wait for it or stop "
                                      "it") from None
                time.sleep(0.1)
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"pid {os.getpid()}: {' '.join(_cmdline())}\n".encode(), 0)
        yield path
    finally:
        with contextlib.suppress(OSError):
            fcntl.flock(fd, fcntl.LOCK_UN)
        os.close(fd)


def _cmdline() -> list[str]:
    try:
        return FsPath("/proc/self/cmdline").read_bytes().decode(errors="replace").split("\0")[:6]
    except OSError:
        return []


# -- the child process -----------------------------------------------------------------------
def _principal(inertia6):
    """Principal moments and the MuJoCo quaternion of their axes, of an inertia about the
    CoM ``[Ixx, Ixy, Ixz, Iyy, Iyz, Izz]``."""
    import mujoco

    ixx, ixy, ixz, iyy, iyz, izz = inertia6
    w, v = np.linalg.eigh(np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]]))
    if np.linalg.det(v) < 0:
        v[:, 0] = -v[:, 0]
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, np.ascontiguousarray(v).ravel())
    return np.maximum(w, 0.0), quat


def put_payload(model, bid: int, p) -> None:
    """Give body ``bid`` of a compiled MuJoCo ``model`` the payload ``p`` (a
    :func:`payload_dict`; None: nothing, mass 0).

    The body was compiled with its inertial frame at its own origin, so MuJoCo marked it
    ``body_sameframe`` and places its CoM at the body's origin whatever ``body_ipos`` and
    ``body_iquat`` say later: the flag is cleared, so that the CoM and the inertia's axes are
    where the payload has them."""
    import mujoco

    model.body_sameframe[bid] = mujoco.mjtSameFrame.mjSAMEFRAME_NONE
    if p is None:
        model.body_mass[bid] = 0.0
        model.body_inertia[bid] = 0.0
        return
    diag, quat = _principal(p["inertia"])
    model.body_mass[bid] = p["mass"]
    model.body_ipos[bid] = p["com"]
    model.body_inertia[bid] = diag
    model.body_iquat[bid] = quat


def holding_torque(model, data, bid: int, dofs) -> list[float]:
    """The joint torque that holds body ``bid``'s weight at ``data.qpos`` (N·m, on ``dofs``):
    ``J_com^T (-m g)``, with ``J_com`` MuJoCo's Jacobian of the body's CoM. ``data`` is a
    scratch ``MjData`` (its kinematics are recomputed here)."""
    import mujoco

    mujoco.mj_kinematics(model, data)
    mujoco.mj_comPos(model, data)
    jacp = np.zeros((3, model.nv))
    mujoco.mj_jacBodyCom(model, data, jacp, None, bid)
    force = -float(model.body_mass[bid]) * np.asarray(model.opt.gravity, dtype=float)
    return [float(v) for v in (jacp[:, dofs].T @ force)]


def _check_franky_sim(frs, sims) -> None:
    """The franky-sim internals this module uses are there (the pinned version's)."""
    from importlib.metadata import version

    have = version("franky-sim")
    missing = [n for n, ok in (
        ("franka_robot_server.SetLoadCommand", hasattr(frs, "SetLoadCommand")),
        ("simulation_server.FrankaRobotServer", hasattr(sims, "FrankaRobotServer")),
        ("FrankaServer's message counter", "_FrankaServer__message_id" in
         frs.FrankaServer.__init__.__code__.co_names)) if not ok]
    if have != FRANKY_SIM_VERSION or missing:
        raise FciSimError(f"franky-sim {have} is installed; the scene is written against "
                          f"franky-sim {FRANKY_SIM_VERSION}" + (f" (missing: {missing})"
                                                                if missing else ""))


def _serve(conn, initial_q, refuse_while_moving: bool, kv) -> None:
    import xml.etree.ElementTree as ET

    import franky_sim
    import mujoco
    from franky_sim import franka_robot_server as frs
    from franky_sim import simulation_server as sims
    from franky_sim.franka_robot_protocol import RobotMode
    from franky_sim.mujoco_simulator import MujocoSimulator

    _check_franky_sim(frs, sims)
    ticks = [0]
    events: list = []
    script = {"q": None, "k": 0, "hold": None, "moving": False}
    grip = {"queue": [], "held": False}
    pause = {"until": 0}

    def now() -> float:
        return ticks[0] * 1e-3

    sim = MujocoSimulator()
    sim.init()
    robot = sim.add_robot(initial_q=tuple(initial_q), **({} if kv is None else {"kv": kv}))
    link7 = next(e for e in sim.worldbody.iter("body") if e.get("name") == "robot0_fr3_link7")
    flange = ET.SubElement(link7, "body", name="iem_payload", pos="0 0 0.107")
    ET.SubElement(flange, "inertial", pos="0 0 0", mass="0", diaginertia="0 0 0")

    class SetLoad(frs.SetLoadCommand):
        """franky-sim's setLoad, refused while the arm moves (a real FR3's answer)."""

        def handle(self, server) -> None:
            if refuse_while_moving and (server.current_motion_id or script["moving"]):
                events.append((now(), "refused", float(self.m_load)))
                self.reply(1)  # SetLoad::Status::kCommandNotPossibleRejected
                return
            super().handle(server)
            events.append((now(), "set_load", [float(self.m_load), list(self.F_x_Cload),
                                               list(self.I_load)]))

    class RobotServer(frs.FrankaRobotServer):
        """franky-sim's robot server with the robot's clock and mode."""

        def send_state(self) -> None:
            if time.monotonic() < pause["until"]:
                return
            self._FrankaServer__message_id = ticks[0]  # the robot's time, in ms since start
            super().send_state()

        @property
        def robot_state(self):
            state = super().robot_state
            return state.replace(robot_mode=RobotMode.kMove) if script["moving"] else state

    frs.SetLoadCommand = SetLoad  # the server's command table is built from these names
    sims.FrankaRobotServer = RobotServer
    server = franky_sim.SimulationServer(sim)  # binds the first free 127.x.y.z
    server.init()
    model = sim.model
    bid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "iem_payload")
    arm_dofs = [int(model.jnt_dofadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT,
                                                       f"robot0_fr3_joint{i}")])
                for i in range(1, 8)]
    rs = server.robot_servers[0]
    client = {"motion": 0, "next_pose": 0}

    scratch = mujoco.MjData(model)  # the truth's own kinematics, apart from the simulation's

    def set_payload(p) -> None:
        put_payload(model, bid, p)
        if p is None:
            events.append((now(), "unmount", None))
            return
        scratch.qpos[:] = sim.data.qpos
        q = [float(v) for v in robot.inner_state.q]
        events.append((now(), "mount", {**p, "q": q,
                                        "gravity_torque": holding_torque(model, scratch, bid,
                                                                         arm_dofs)}))

    def pre_step(_sim) -> None:
        ticks[0] += 1
        if grip["queue"] or grip["held"]:
            closed = robot.hand_width < GRASP_WIDTH_M
            if closed and not grip["held"] and grip["queue"]:
                set_payload(grip["queue"].pop(0))
                grip["held"] = True
            elif not closed and grip["held"]:
                set_payload(None)
                grip["held"] = False
        motion = rs.current_motion_id
        if motion != client["motion"]:
            events.append((now(), "motion_start" if motion else "motion_end", "client"))
            client["motion"] = motion
        moving = bool(motion) or script["moving"]
        if moving and ticks[0] >= client["next_pose"]:
            client["next_pose"] = ticks[0] + round(POSE_PERIOD_S * 1e3)
            events.append((now(), "pose", list(robot.inner_state.q)))
        if motion:  # a client's motion takes the arm over
            script.update(q=None, hold=None, moving=False)
            return
        if script["q"] is not None:
            k = script["k"]
            if k < len(script["q"]):
                robot.joint_position_control(script["q"][k])
                script["k"] = k + 1
                return
            script.update(hold=script["q"][-1], q=None, moving=False)
            events.append((now(), "motion_end", "program"))
        if script["hold"] is not None:
            robot.joint_position_control(script["hold"])

    sim.register_pre_step_callback(pre_step)
    conn.send(("ready", robot.hostname))

    def status() -> dict:
        st = robot.inner_state
        return {"t": now(), "moving": bool(rs.current_motion_id) or script["moving"],
                "q": list(st.q), "m_load": float(robot.m_load), "held": grip["held"],
                "queued": len(grip["queue"])}

    # Commands arrive through a thread of their own: the scene's loop never waits in a
    # ``recv`` for the rest of a message (a parent sends a long path in pieces, and its
    # next piece may wait on a state this loop would not send meanwhile).
    inbox: queue.Queue = queue.Queue()

    def receive() -> None:
        while True:
            try:
                inbox.put(conn.recv())
            except (EOFError, OSError):
                inbox.put(("gone", None))  # the parent ended
                return

    threading.Thread(target=receive, name="commands", daemon=True).start()
    try:
        while True:
            while not inbox.empty():
                cmd, arg = inbox.get_nowait()
                if cmd == "gone":
                    return
                if cmd == "stop":
                    conn.send(("ok", None))
                    return
                if cmd == "mount":
                    set_payload(arg)
                elif cmd == "unmount":
                    set_payload(None)
                elif cmd == "grasp_queue":
                    grip["queue"] = list(arg)
                elif cmd == "play":
                    script.update(q=np.asarray(arg, dtype=float), k=0, hold=None, moving=True)
                    events.append((now(), "motion_start", "program"))
                elif cmd == "pause":
                    pause["until"] = time.monotonic() + float(arg)
                elif cmd == "events":
                    conn.send(("ok", list(events)))
                    continue
                conn.send(("ok", status()))
            server.run_once(True)
    finally:
        server.cleanup()
        sim.cleanup()


# -- the parent's handle ---------------------------------------------------------------------
def payload_dict(payload) -> dict | None:
    """A :class:`iem.payload.Payload` as the scene takes it (None: none)."""
    if payload is None:
        return None
    return {"name": payload.name, "mass": float(payload.mass),
            "com": [float(v) for v in payload.com],
            "inertia": [float(v) for v in payload.inertia]}


class FciSim:
    """franky-sim's FR3 in a child process (see the module docstring).

    Args:
        initial_q: the arm's configuration at start, rad (None: the FR3's home,
            :attr:`sim.description.ArmDescription.home`).
        refuse_while_moving: answer ``setLoad`` "not possible" while the arm moves.
        kv: joint D gains (None: franky-sim's own, which ring; default :data:`STABLE_KV`).
        lock_timeout: how long to wait for another scene to end, s.
    """

    def __init__(self, initial_q=None, *, refuse_while_moving: bool = True,
                 kv=STABLE_KV, lock_timeout: float = LOCK_TIMEOUT_S) -> None:
        if initial_q is None:
            from sim.description import arm_description

            initial_q = arm_description("fr3").home
        self._lock = scene_lock(lock_timeout)
        self._lock.__enter__()
        try:
            ctx = mp.get_context("spawn")
            self._conn, child = ctx.Pipe()
            self._proc = ctx.Process(target=_serve, name="franky-sim", daemon=True,
                                     args=(child, [float(v) for v in initial_q],
                                           bool(refuse_while_moving),
                                           None if kv is None else tuple(kv)))
            self._proc.start()
            child.close()
            if not self._conn.poll(START_TIMEOUT_S):
                raise FciSimError(f"franky-sim did not start within {START_TIMEOUT_S:g} s")
            _, self.host = self._conn.recv()
        except BaseException:
            self.close()
            raise

    @property
    def pid(self) -> int:
        """The process id of the simulator's process (franky-sim's server runs there)."""
        return self._proc.pid

    def _call(self, cmd: str, arg=None, timeout: float = CALL_TIMEOUT_S):
        if not self._proc.is_alive():
            raise FciSimError(f"franky-sim ended (exit code {self._proc.exitcode})")
        self._conn.send((cmd, arg))
        if not self._conn.poll(timeout):
            raise FciSimError(f"franky-sim did not answer {cmd!r} within {timeout:g} s")
        _, value = self._conn.recv()
        return value

    # -- the scene -------------------------------------------------------------------------
    def mount(self, payload) -> dict:
        """Fix ``payload`` (a :class:`iem.payload.Payload`) to the flange now."""
        return self._call("mount", payload_dict(payload))

    def unmount(self) -> dict:
        """Take the payload off the flange now."""
        return self._call("unmount")

    def grasp_queue(self, payloads) -> dict:
        """The payloads the hand picks up, one each time it closes (removed when it opens)."""
        return self._call("grasp_queue", [payload_dict(p) for p in payloads])

    def play(self, q) -> dict:
        """Move the arm along the joint positions ``q`` ``(N, 7)``, one a millisecond (the
        robot's own program; :class:`sim.joint_path.Path` ``.q``)."""
        return self._call("play", np.asarray(q, dtype=float))

    def pause(self, seconds: float) -> dict:
        """Send no state for ``seconds`` of the wall clock (a lost network: the robot's own
        clock runs on, and its scene may step faster than real time while no state is
        sent)."""
        return self._call("pause", float(seconds))

    def status(self) -> dict:
        """``t`` (the robot's time, s), ``moving``, ``q``, ``m_load``, ``held``, ``queued``."""
        return self._call("status")

    def events(self) -> list:
        """The truth log: ``(t, kind, data)`` in the robot's time (see the module
        docstring)."""
        return self._call("events")

    def wait(self, seconds: float, poll: float = 0.02) -> dict:
        """Until ``seconds`` of the robot's time have passed."""
        end = self.status()["t"] + seconds
        while True:
            st = self.status()
            if st["t"] >= end:
                return st
            time.sleep(poll)

    def wait_still(self, timeout: float = 120.0, poll: float = 0.02) -> dict:
        """Until no motion runs (wall-clock ``timeout``, s)."""
        deadline = time.monotonic() + timeout
        while True:
            st = self.status()
            if not st["moving"]:
                return st
            if time.monotonic() > deadline:
                raise FciSimError(f"the arm still moves after {timeout:g} s")
            time.sleep(poll)

    # -- life ------------------------------------------------------------------------------
    def close(self) -> None:
        """Stop the simulator (its process ends) and release the lock."""
        proc = getattr(self, "_proc", None)
        try:
            if proc is not None and proc.is_alive():
                with contextlib.suppress(Exception):
                    self._call("stop", timeout=5.0)
                proc.join(5.0)
                if proc.is_alive():
                    proc.kill()
                    proc.join(5.0)
        finally:
            lock, self._lock = getattr(self, "_lock", None), None
            if lock is not None:
                lock.__exit__(None, None, None)

    def __enter__(self) -> FciSim:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

