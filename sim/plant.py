"""The MuJoCo plant that stands in for the real arm, and its sensor model.

The plant is MuJoCo's model of the same arm (its description, :mod:`sim.description`, read
without meshes; a gripper's fingers welded, joint damping, armature and friction zeroed,
contacts and joint limits off; :mod:`sim.mujoco_model`) with its end effector and the payload
as bodies on the flange. The payload's mass, CoM and inertia can be changed between two steps
without rebuilding the model.

Each 1 ms step a computed-torque controller, running on the controller's arm model (the
nominal Pinocchio model, or a calibrated arm: ``controller_arm``) with the load the
controller has been told about (``set_controller_load``, libfranka's ``setLoad``), computes
``tau = M(q)(ddq_d + Kp e + Kd de) + h(q, dq)`` (plus the friction that arm model knows) from
the arm's own joint state (its encoders, finer than the measurement model below: feeding the
noisy measurement back through a stiff loop would shake the arm with about 1 rad/s² of
acceleration noise), applies it, and MuJoCo integrates (semi-implicit Euler). The step
reports what a Franka reports: measured ``q``, ``dq`` and the link-side torque ``tau_J``,
each with the sensor noise of :class:`iem.sensor.SensorModel` (re-exported here).

Sensor model (defaults; later work measures against them): independent white Gaussian noise
per joint and sample, ``sigma_q = 1e-4 rad``, ``sigma_dq = 2e-3 rad/s``,
``sigma_tau = 0.05 N·m``. Seeded: the same seed gives the same noise.

Reality gap (optional, :class:`~sim.reality_gap.RealityGap`, with the plant's MuJoCo model in
:mod:`sim.mujoco_model`; both importable from here): how the simulated real arm departs from the
nominal model that the controller, the tandem simulators and the estimators use, all drawn
from one seed. Part of it an arm model describes (:meth:`RealityGap.realise` gives it as
:class:`sim.arm.ArmParams`, what a perfect calibration would find): link masses, CoMs and
inertias, joint friction (Coulomb, viscous and Stribeck, per direction:
:func:`sim.friction.friction_torque`) and torque-sensor offsets. MuJoCo integrates the perturbed
links under the applied torque minus the friction; the measured ``tau_J`` is the applied
torque plus the offset, so that ``tau_J = RNEA_arm(q, dq, ddq) + tau_f(dq) + offset``
(``ArmModel(arm=...).rnea``). The rest no arm model here describes
(:class:`Unmodelled`): friction that changes with load and as the joints warm, a position
ripple, the torque sensor's gain error and the slow drift of its offset; it is what a
calibrated arm leaves in the residual, tuned to look like a real Panda's (the one
recording of a real arm there is).
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
import pinocchio as pin

from iem.sensor import SensorModel
from iem.types import JointState

from .arm import ArmParams
from .friction import friction_torque
from .mujoco_model import DT, PAYLOAD_BODY, build_mujoco_model, payload_principal
from .payload import Payload
from .reality_gap import RealityGap, Unmodelled
from .robot import ArmModel

__all__ = ["DT", "ArmPlant", "Gains", "RealityGap", "Rollout", "SensorModel", "Unmodelled",
           "build_mujoco_model"]


@dataclass(frozen=True)
class Gains:
    """Computed-torque gains: ``ddq_cmd = ddq_d + kp (q_d - q) + kd (dq_d - dq)``.

    A stiff joint-level loop, as the Franka's own: 100 rad/s natural frequency, critically
    damped. With the default test payload on the flange and no load set in the controller it
    tracks the excitation path within 3 mrad (at 20 rad/s it drifted 64 mrad, and estimators
    trained on the planned path met accelerations they never saw).

    Attributes:
        kp: 1/s² (10000).
        kd: 1/s (200).
    """

    kp: float = 10000.0
    kd: float = 200.0




def _has_friction(friction: np.ndarray) -> bool:
    """Whether a friction array (:func:`sim.friction.friction_torque`) gives any torque."""
    amplitudes = (0, 3, 4, 5, 6) if friction.shape[1] > 3 else (0,)
    return bool(np.any(friction[:, amplitudes]))


class ArmPlant:
    """The simulated robot: MuJoCo arm, payload, computed-torque control and sensors.

    Args:
        payload: the payload on the flange (None: nothing mounted).
        sensor: measurement noise; ``SensorModel.noiseless()`` for exact readings.
        gap: optional reality gap: how the plant's arm departs from the nominal model
            (links, friction, offsets); ``arm`` is then that arm as an
            :class:`sim.arm.ArmParams` (None without a gap).
        seed: seed of the sensor noise.
        gains: tracking controller gains.
        controller_load: the load the controller believes is mounted (libfranka's
            ``setLoad``); None: no load.
        controller_arm: the arm model the controller computes its torques with
            (:class:`sim.arm.ArmParams`, e.g. a calibrated one; its friction is compensated,
            its offsets are the sensors' and play no part); None: the nominal model.
        description: the arm model (:mod:`sim.description`) when ``controller_arm`` is None;
            None: the default.
        end_effector: what the flange carries (:mod:`sim.end_effector`; None: the arm
            model's default), on the plant and on the controller's nominal model.
    """

    def __init__(self, payload: Payload | None = None, sensor: SensorModel | None = None,
                 gap: RealityGap | None = None, seed: int = 0, gains: Gains | None = None,
                 controller_load: Payload | None = None,
                 controller_arm: ArmParams | None = None, description=None,
                 end_effector: str | None = None) -> None:
        from .description import described

        self.description = (controller_arm.description if controller_arm is not None
                            else described(description))
        if controller_arm is None and end_effector:
            controller_arm = ArmParams.nominal(end_effector, self.description)
        self.end_effector = end_effector
        self.sensor = SensorModel() if sensor is None else sensor
        self.gap = gap
        self.seed = seed
        self.gains = Gains() if gains is None else gains
        self.model = build_mujoco_model(self.description, end_effector)
        self.data = mujoco.MjData(self.model)
        self._scratch = mujoco.MjData(self.model)
        self._payload_id = self.model.body(PAYLOAD_BODY).id
        self.arm: ArmParams | None = None
        self._friction = self._offset = self._unmodelled = None
        if gap is not None:
            self._apply_gap(gap)
        self._rng = np.random.default_rng(seed)
        self._sigmas = self.sensor.sigmas
        self._noisy = bool(np.any(self._sigmas > 0))
        self.controller_arm = controller_arm
        self._ctrl_friction = (None if controller_arm is None
                               or not _has_friction(controller_arm.friction)
                               else controller_arm.friction)
        self._ctrl = ArmModel(arm=controller_arm, description=self.description)
        self._ctrl_model = self._ctrl.model.copy()
        self._ctrl_data = self._ctrl_model.createData()
        self._ctrl_link7 = self._ctrl_model.inertias[self._ctrl.last_joint].copy()
        self.payload: Payload | None = None
        self.controller_load: Payload | None = None
        self.set_payload(payload)
        self.set_controller_load(controller_load)
        self.cycle = 0
        self._run_time = 0.0  # s run before the last reset
        self.last_tau = np.zeros(7)
        self.last_ddq = np.zeros(7)

    # -- configuration ---------------------------------------------------------------------
    def _apply_gap(self, gap: RealityGap) -> None:
        desc = self.description
        self.arm = gap.realise(self.model, desc, self.end_effector)
        m = self.model
        for name, (mass, com, moments) in zip(desc.link_bodies, gap.bodies(self.model, desc),
                                              strict=True):
            b = m.body(name).id
            m.body_mass[b] = mass
            m.body_inertia[b] = moments
            m.body_ipos[b] = com
        self._set_const()
        self._friction = self.arm.friction if _has_friction(self.arm.friction) else None
        self._offset = self.arm.offset
        unmodelled = gap.unmodelled(desc)
        self._unmodelled = unmodelled if unmodelled.any else None

    def _set_const(self) -> None:
        # mj_setConst works at qpos0 and would overwrite the state: give it scratch data.
        mujoco.mj_setConst(self.model, self._scratch)

    def set_payload(self, payload: Payload | None) -> None:
        """Mount ``payload`` on the flange (None: remove it), between two steps."""
        m, b = self.model, self._payload_id
        if payload is None:
            m.body_mass[b] = 0.0
            m.body_ipos[b] = 0.0
            m.body_inertia[b] = 0.0
            m.body_iquat[b] = (1.0, 0.0, 0.0, 0.0)
        else:
            payload.check()
            moments, quat = payload_principal(payload)
            m.body_mass[b] = payload.mass
            m.body_ipos[b] = payload.com
            m.body_inertia[b] = moments
            m.body_iquat[b] = quat
        self._set_const()
        self.payload = payload

    def set_controller_load(self, load: Payload | None) -> None:
        """Tell the controller which load is mounted (libfranka ``setLoad`` semantics)."""
        inertia = self._ctrl_link7
        if load is not None:
            load.check()
            inertia = inertia + self._ctrl.payload_inertia_in_joint(load.to_phi())
        self._ctrl_model.inertias[self._ctrl.last_joint] = inertia
        self.controller_load = load

    # -- state -----------------------------------------------------------------------------
    def reset(self, q, dq=None) -> None:
        """Put the arm at ``q`` (rad) with velocity ``dq`` (rad/s, default 0). The clock of
        the gap's slow effects (warm-up, offset drift) runs on: they go by the time the
        plant has run since it was built, as a real arm's temperature does."""
        self._run_time += float(self.data.time)
        mujoco.mj_resetData(self.model, self.data)
        self.data.qpos[:] = np.asarray(q, dtype=float)
        self.data.qvel[:] = 0.0 if dq is None else np.asarray(dq, dtype=float)
        mujoco.mj_forward(self.model, self.data)
        self.cycle = 0

    @property
    def time(self) -> float:
        return float(self.data.time)

    @property
    def q(self) -> np.ndarray:
        """True joint positions, rad."""
        return self.data.qpos.copy()

    @property
    def dq(self) -> np.ndarray:
        """True joint velocities, rad/s."""
        return self.data.qvel.copy()

    # -- stepping --------------------------------------------------------------------------
    def step(self, q_d, dq_d, ddq_d) -> JointState:
        """One 1 ms control cycle toward the reference; returns the measured joint state.

        The returned state holds the measurement taken at the start of the cycle and the
        torque applied during it as the sensor reads it (plus its offset; ``last_tau``,
        noise-free); ``last_ddq`` is the true acceleration of that cycle, so that
        ``RNEA(q_true, dq_true, last_ddq) == last_tau`` with the mounted payload, ``RNEA`` of
        the plant's arm (``ArmModel(arm=plant.arm)``: its links, friction and offsets),
        up to what the gap leaves unmodelled (:class:`Unmodelled`; without it: exactly).
        """
        d = self.data
        t = float(d.time)
        q_true = d.qpos.copy()
        dq_true = d.qvel.copy()
        if self._noisy:
            noise = self._rng.standard_normal(21) * self._sigmas
            q_m = q_true + noise[:7]
            dq_m = dq_true + noise[7:14]
        else:
            noise = None
            q_m, dq_m = q_true, dq_true
        g = self.gains
        # the joint loop runs on the arm's own encoders (the true state here); the sensor
        # model is what the measurement reported over the bus carries
        ddq_cmd = ddq_d + g.kp * (q_d - q_true) + g.kd * (dq_d - dq_true)
        tau = np.array(pin.rnea(self._ctrl_model, self._ctrl_data, q_true, dq_true, ddq_cmd))
        if self._ctrl_friction is not None:
            tau += friction_torque(dq_true, self._ctrl_friction)
        # the links move under the applied torque less the joint friction (and what the gap
        # leaves unmodelled); the torque sensor reads the applied torque plus its offset
        u = self._unmodelled
        if u is None:
            d.qfrc_applied[:] = (tau if self._friction is None
                                 else tau - friction_torque(dq_true, self._friction))
            sensed = tau
        else:
            age = self._run_time + t
            lost = u.position_torque(q_true)
            if self._friction is not None:
                lost += friction_torque(dq_true, self._friction) * u.friction_scale(age, tau)
            d.qfrc_applied[:] = tau - lost
            sensed = u.sensor(age, tau)
        mujoco.mj_step(self.model, d)
        self.last_tau = sensed if self._offset is None else sensed + self._offset
        self.last_ddq = d.qacc.copy()
        self.last_q = q_true
        self.last_dq = dq_true
        tau_m = self.last_tau + noise[14:] if noise is not None else self.last_tau
        state = JointState(t=t, q=q_m, dq=dq_m, tau_J=tau_m, cycle=self.cycle)
        self.cycle += 1
        return state

    def follow(self, path, reset: bool = True, mount: dict | None = None) -> Rollout:
        """Track a :class:`sim.paths.Path` sample by sample and record everything.

        ``mount`` maps sample indices to payloads (or None): each is mounted
        (:meth:`set_payload`) just before that sample's step, e.g. ``{3000: other}`` swaps the
        payload at 3 s. The controller keeps the load it was told about.
        """
        n = len(path)
        if reset:
            self.reset(path.q[0], path.dq[0])
        mount = {} if mount is None else dict(mount)
        out = Rollout.empty(n)
        for k in range(n):
            if k in mount:
                self.set_payload(mount[k])
            s = self.step(path.q[k], path.dq[k], path.ddq[k])
            out.t[k] = s.t
            out.q[k], out.dq[k], out.tau[k] = s.q, s.dq, s.tau_J
            out.q_true[k], out.dq_true[k] = self.last_q, self.last_dq
            out.ddq_true[k], out.tau_true[k] = self.last_ddq, self.last_tau
            out.q_ref[k] = path.q[k]
        return out


@dataclass
class Rollout:
    """What the plant did along a path: measured and true signals, one row per 1 ms cycle.

    Attributes:
        t: s; q, dq, tau: measured (rad, rad/s, N·m); q_true, dq_true, ddq_true, tau_true:
        the true state, acceleration and torque (applied plus offset, noise-free); q_ref:
        the reference, rad.
    """

    t: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    tau: np.ndarray
    q_true: np.ndarray
    dq_true: np.ndarray
    ddq_true: np.ndarray
    tau_true: np.ndarray
    q_ref: np.ndarray

    @classmethod
    def empty(cls, n: int) -> Rollout:
        return cls(np.zeros(n), *(np.zeros((n, 7)) for _ in range(8)))

    def __len__(self) -> int:
        return len(self.t)

    @property
    def features(self) -> np.ndarray:
        """Learner inputs ``[q, dq, tau]`` per cycle, ``(N, 21)``."""
        return np.hstack((self.q, self.dq, self.tau))
