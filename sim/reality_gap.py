"""How the simulated real arm departs from the nominal model (:class:`RealityGap`), all
drawn from one seed: the part an arm model describes (links, friction, torque offsets:
:meth:`RealityGap.realise`) and the part none here does (:class:`Unmodelled`: friction that
changes with load and warm-up, position ripples, the torque sensor's gain error and drift)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import mujoco
import numpy as np
import pinocchio as pin

from .arm import ArmParams
from .description import described
from .friction import GAZ_PHI, full_friction
from .mujoco_model import build_mujoco_model


@dataclass(frozen=True, eq=False)
class Unmodelled:
    """What the plant does that no arm model here describes, per joint, drawn by
    :meth:`RealityGap.unmodelled`. At time ``t`` (s the plant has run, resets included),
    joint state ``q``, ``dq`` and applied torque ``tau``, the links move under ``tau`` less::

        tau_f(dq) (1 + load |tau| / tau_max) (1 - warmup (1 - exp(-t / WARMUP_S)))
        + sum_i ripple_i sin(wavenumber_i q + ripple_phase_i)

    (``tau_f`` the arm's friction, :func:`sim.friction.friction_torque`; two ripples, a slow and
    a fast one), and the torque sensor reads
    ``(1 + gain) tau + drift sin(2 pi t / drift_period + drift_phase)`` plus the arm's
    constant offset.

    Attributes:
        load: friction's growth with the joint's load, at the rated torque (-), ``(7,)``.
        warmup: friction's fall as the joint warms, in the end (-; time constant
            :data:`WARMUP_S`), ``(7,)``.
        gain: the torque sensor's gain error (-), ``(7,)``.
        ripple: amplitudes of the position ripples, N·m, ``(7, 2)``; wavenumber rad⁻¹ and
            ripple_phase rad, the same shape.
        drift: amplitude of the sensor offset's slow drift, N·m, ``(7,)``; drift_period s,
            drift_phase rad, the same shape.
    """

    load: np.ndarray
    warmup: np.ndarray
    gain: np.ndarray
    ripple: np.ndarray
    wavenumber: np.ndarray
    ripple_phase: np.ndarray
    drift: np.ndarray
    drift_period: np.ndarray
    drift_phase: np.ndarray
    tau_max: np.ndarray
    """The arm's torque limits, N·m, ``(7,)``, the scale of the load dependence."""

    @property
    def any(self) -> bool:
        """Whether any effect is there."""
        return bool(np.any(self.load) or np.any(self.warmup) or np.any(self.gain)
                    or np.any(self.ripple) or np.any(self.drift))

    def friction_scale(self, t: float, tau) -> np.ndarray:
        """The factor on the arm's friction at time ``t`` under the applied torque ``tau``."""
        return ((1.0 + self.load * np.abs(tau) / self.tau_max)
                * (1.0 - self.warmup * (1.0 - np.exp(-t / WARMUP_S))))

    def position_torque(self, q) -> np.ndarray:
        """The position ripples at ``q``, N·m."""
        return np.sum(self.ripple * np.sin(self.wavenumber * np.asarray(q)[:, None]
                                           + self.ripple_phase), axis=1)

    def sensor(self, t: float, tau) -> np.ndarray:
        """What the torque sensor reads of the applied ``tau`` at time ``t``, less the arm's
        constant offset."""
        return ((1.0 + self.gain) * tau
                + self.drift * np.sin(2.0 * np.pi * t / self.drift_period + self.drift_phase))


WARMUP_S = 600.0
"""Time constant of the joints' warm-up (:attr:`Unmodelled.warmup`), s."""
def large_drives(tau_max: np.ndarray) -> np.ndarray:
    """The joints with the large drives (the Panda's and FR3's 1-4): torque limits of at least
    half the largest."""
    tau_max = np.asarray(tau_max, dtype=float)
    return tau_max >= 0.5 * tau_max.max()


@dataclass(frozen=True)
class RealityGap:
    """How the plant's arm departs from the nominal model, drawn from ``seed``.

    What an arm model (:class:`sim.arm.ArmParams`, :meth:`realise`) describes, and a
    calibration can identify:

    - per link body (the description's ``link_bodies``, each in its own frame): the mass scaled by
      ``1 + mass_rel u``, the principal moments about the CoM by ``1 + inertia_rel u`` (each,
      principal axes kept), the CoM moved by ``com_abs u`` per axis, ``u ~ U(-1, 1)``;
    - per joint, friction (:func:`sim.friction.friction_torque`): Gaz's
      (:data:`sim.friction.GAZ_PHI`) with each of ``phi1, phi2, phi3`` multiplied by a factor
      drawn in ``friction_factor``;
      viscous friction ``U(0, viscous)`` N·m·s/rad, and a Stribeck excess
      ``U(0, stribeck) phi1`` at a Stribeck velocity ``U(*stribeck_vs)``, each drawn for
      either direction of motion;
    - a torque-sensor offset per joint ``~ N(0, offset_std²)``.

    What no arm model here describes (:class:`Unmodelled`, :meth:`unmodelled`), which a
    calibrated arm leaves in the residual, per joint:

    - friction that grows with the joint's load, by ``U(0, load_friction)`` at the rated
      torque (the arm model's, :class:`sim.description.Limits`), and falls by
      ``U(0, warmup)`` as the joint warms (time constant :data:`WARMUP_S`, over the time the
      plant has run);
    - a torque-sensor gain error ``U(-gain_rel, gain_rel)`` and a slow drift of its offset,
      ``U(0, offset_drift)`` N·m in a sine of period ``U(*drift_period_s)`` s;
    - two position ripples ``a sin(k q + phase)``, a slow one and a fast one (the fast one
      passes 3-10 Hz at the motion's speeds): ``a ~ U(0.5, 1)`` times ``ripple_large``
      (the large drives, :func:`large_drives`) or ``ripple_small`` (the others), N·m,
      ``k ~ U(*ripple_wavenumber[i])`` rad⁻¹, ``phase ~ U(0, 2 pi)``.

    The defaults are tuned on gap seeds 10-12 so that the calibrated arm's held-out residual
    has the size and the colour of a real Panda's (docs/benchmarks.md, "The plants"). Body 7
    keeps the end effector :meth:`realise` is given. Each group of draws has its own stream of
    ``seed``: the links, Gaz's factors and the offsets of a seed are the same whatever the
    other bounds.

    Attributes:
        mass_rel: relative mass error bound (-, default 0.05).
        inertia_rel: relative inertia error bound (-, default 0.10).
        com_abs: CoM error bound per axis, m (default 0.005).
        friction_factor: ``(low, high)`` of the factor on Gaz's values (default 0.7-1.3),
            or None: no friction at all.
        viscous: bound of the viscous coefficients, N·m·s/rad.
        stribeck: bound of the Stribeck excess, relative to ``phi1``.
        stribeck_vs: ``(low, high)`` of the Stribeck velocities, rad/s.
        offset_std: standard deviation of the torque offsets, N·m (default 0.1).
        load_friction, warmup, gain_rel, offset_drift, drift_period_s, ripple_large,
            ripple_small, ripple_wavenumber: the unmodelled effects' bounds (above).
        seed: random seed of the whole departure.
    """

    mass_rel: float = 0.05
    inertia_rel: float = 0.10
    com_abs: float = 0.005
    friction_factor: tuple[float, float] | None = (0.7, 1.3)
    viscous: float = 0.1
    stribeck: float = 0.4
    stribeck_vs: tuple[float, float] = (0.05, 0.3)
    offset_std: float = 0.1
    load_friction: float = 0.5
    warmup: float = 0.2
    gain_rel: float = 0.02
    offset_drift: float = 0.1
    drift_period_s: tuple[float, float] = (60.0, 240.0)
    ripple_large: tuple[float, float] = (0.2, 0.2)
    ripple_small: tuple[float, float] = (0.06, 0.06)
    ripple_wavenumber: tuple[tuple[float, float], tuple[float, float]] = ((0.5, 3.0),
                                                                          (25.0, 60.0))
    seed: int = 0

    def modelled_only(self) -> RealityGap:
        """This gap without its unmodelled effects: what an arm model describes exactly
        (the same links, friction and offsets)."""
        return replace(self, load_friction=0.0, warmup=0.0, gain_rel=0.0, offset_drift=0.0,
                       ripple_large=(0.0, 0.0), ripple_small=(0.0, 0.0))

    def bodies(self, model: mujoco.MjModel,
               description=None) -> list[tuple[float, np.ndarray, np.ndarray]]:
        """The perturbed link bodies ``(mass, com (3,), principal moments (3,))`` in their
        frames (principal axes unchanged), from the nominal bodies of ``model`` (a fresh
        plant model of the arm model ``description``, None: the default)."""
        rng = np.random.default_rng(self.seed)
        out = []
        for name in described(description).link_bodies:
            b = model.body(name)
            mass = float(b.mass[0]) * (1.0 + self.mass_rel * rng.uniform(-1, 1))
            moments = b.inertia * (1.0 + self.inertia_rel * rng.uniform(-1, 1, 3))
            com = b.ipos + self.com_abs * rng.uniform(-1, 1, 3)
            out.append((mass, com, moments))
        return out

    def joints(self) -> tuple[np.ndarray, np.ndarray]:
        """The friction (``(7, 9)``, or ``(7, 3)`` Gaz's alone when ``viscous`` and
        ``stribeck`` are 0) and the offsets ``(7,)`` (drawn after the bodies)."""
        rng = np.random.default_rng([self.seed, 1])
        if self.friction_factor is None:
            friction = np.zeros((7, 3))
        else:
            lo, hi = self.friction_factor
            friction = GAZ_PHI * rng.uniform(lo, hi, (7, 3))
        offset = self.offset_std * rng.standard_normal(7)
        if self.friction_factor is not None and (self.viscous or self.stribeck):
            more = np.random.default_rng([self.seed, 2])
            friction = full_friction(friction)
            friction[:, 3:5] = self.viscous * more.uniform(0.0, 1.0, (7, 2))
            friction[:, 5:7] = self.stribeck * more.uniform(0.0, 1.0, (7, 2)) * friction[:, :1]
            friction[:, 7:9] = more.uniform(*self.stribeck_vs, (7, 2))
        return friction, offset

    def unmodelled(self, description=None) -> Unmodelled:
        """The effects no arm model describes (:class:`Unmodelled`) on the arm model
        ``description`` (None: the default), from their own stream of the seed (each drawn
        whatever the others' bounds)."""
        tau_max = described(description).limits.tau_max
        rng = np.random.default_rng([self.seed, 3])
        u = lambda lo=0.0, hi=1.0, shape=7: rng.uniform(lo, hi, shape)  # noqa: E731
        size = np.where(large_drives(tau_max)[:, None], self.ripple_large, self.ripple_small)
        (k0, k1), (k2, k3) = self.ripple_wavenumber
        return Unmodelled(
            load=self.load_friction * u(), warmup=self.warmup * u(),
            gain=self.gain_rel * u(-1.0), ripple=size * u(0.5, 1.0, (7, 2)),
            wavenumber=np.column_stack((u(k0, k1), u(k2, k3))),
            ripple_phase=u(0.0, 2.0 * np.pi, (7, 2)),
            drift=self.offset_drift * u(), drift_period=u(*self.drift_period_s),
            drift_phase=u(0.0, 2.0 * np.pi), tau_max=tau_max)

    def realise(self, model: mujoco.MjModel | None = None, description=None,
                end_effector: str | None = None) -> ArmParams:
        """The arm this gap describes on the arm model ``description`` (None: the default),
        as the arm model uses it (Pinocchio joint bodies: the nominal ones with each link's
        perturbation added; body 7 keeps ``end_effector``, None: the arm model's default);
        ``model``: the plant's MuJoCo model of it (None: a fresh one)."""
        from .end_effector import end_effector_of
        from .robot import nominal_link_params

        desc = described(description)
        model = build_mujoco_model(desc, end_effector) if model is None else model
        params = nominal_link_params(end_effector, desc)
        for j, (name, (mass, com, moments)) in enumerate(
                zip(desc.link_bodies, self.bodies(model, desc), strict=True)):
            b = model.body(name)
            rot = np.empty(9)
            mujoco.mju_quat2Mat(rot, b.iquat)
            rot = rot.reshape(3, 3)
            nominal = pin.Inertia(float(b.mass[0]), b.ipos.copy(),
                                  rot @ np.diag(b.inertia) @ rot.T)
            real = pin.Inertia(mass, com, rot @ np.diag(moments) @ rot.T)
            params[j] += real.toDynamicParameters() - nominal.toDynamicParameters()
        friction, offset = self.joints()
        return ArmParams(params, friction, offset, {"source": f"reality gap {self}"},
                         end_effector=end_effector_of(end_effector, desc).label,
                         description=desc)
