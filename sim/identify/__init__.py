"""Offline commissioning identification: a payload from a loaded and a bare recording.

``identify(loaded, bare)`` (or ``identify(loaded, arm=ARM)``) takes recorded joint states (the
arrays ``t, q, dq, tau`` at 1 kHz or any rate, in any form
:func:`iem.signals.recording.as_recording` accepts) and returns an :class:`Identification`: the
payload's ten parameters, physically consistent, with their covariance, and which of them the
data determine and which the prior.

Method (offline, so the filters may be non-causal):

1. **Signals** (:func:`iem.signals.offline.prepare`, the offline chain ``iem calibrate`` uses
   too). Each recording is split where its time stamps jump by more than 50 ms (nothing is
   invented across a gap; pieces too short to filter are dropped) and each piece goes on a
   uniform time grid at the median rate where its clock jitters by more than 1 %; spikes
   (single corrupt samples, more than 6 robust standard deviations from a local quadratic
   fit) are replaced by that fit; ``q``, ``dq`` and ``tau`` go through a zero-phase
   Butterworth low-pass (order 4, ``cutoff_hz`` = 10 Hz: no lag, so every signal lines up
   with every other); ``ddq`` is the central difference of the filtered ``dq``; the result
   is taken every ``1/rate_hz`` s (100 Hz; the low-pass is the anti-alias filter),
   ``edge_s`` trimmed at both ends of each piece.
2. **Alignment.** The bare recording is moved in time onto the loaded one by the peak of the
   cross-correlation of their filtered joint velocities (sub-sample, parabolic), and sampled
   at the loaded recording's instants inside a piece of both. The two must be the same
   motion: on the overlap (at least ``min_overlap_s``) no joint may differ by more than
   ``path_tol`` rad, else :class:`MismatchedLogsError`.
3. **Residual torques.** ``r = (tau_L - tau_nom(x_L)) - (tau_B - tau_nom(x_B))``, ``tau_nom``
   the nominal Panda's RNEA at each recording's own filtered state. What the nominal model
   gets wrong about the arm (links, friction, torque offsets) is nearly the same in both and
   cancels; the small difference between the two actual motions (the loaded arm tracks a few
   mrad differently) is accounted for by the model instead of being read as payload. With an
   arm file instead of a bare recording, ``r = tau_L - tau_arm(x_L)`` for any motion.
4. **Robust weighted least squares.** ``r = Y(x_L) phi + c lead + e`` with ``Y`` the flange
   body regressor of :class:`sim.robot.ArmModel`, and ``c`` the time derivative of the
   torques that enter ``r``: a torque sample may belong to a slightly later instant than the
   joint state it comes with (the project's plant reports the torque applied over the
   following 1 ms cycle, half a cycle ahead; a real sensor has its own delay), so that lead is
   estimated with the payload (prior 0 ± 2 ms) and marginalised out; it is reported as
   ``tau_lead_s``. Rows are weighted by the inverse variance of their joint's residual (a
   robust scale, 1.4826 MAD) times Huber weights (``huber`` = 1.345 scale units, iteratively
   reweighted), so that a disturbance longer than a spike (a touch, a cable pulling) pulls
   with bounded force.
5. **Prior.** A stated weak Gaussian prior: standard deviations of the Panda's rated payload
   (:data:`iem.physics.posterior.DEFAULT_PRIOR_STD`: 3 kg, 0.3 kg·m, 0.01 kg·m²); zero mean for
   the mass and the first moments, and for the inertia about the flange the inertia of a
   point mass at the CoM a first fit found (refit once from there): a body whose CoM is far
   from the flange has at least that inertia about it, so a zero mean would contradict it
   (a 2.8 kg tool 0.1 m off-axis on the unexciting 6 s task path was refused as "not a rigid
   body" with it). On an exciting motion the data determine every parameter thousands of
   times better and the prior moves nothing; it only keeps unexcited directions finite.
6. **Physical consistency.** The weighted least-squares cost is ``(phi - phi_hat)^T H (phi -
   phi_hat) + const``, ``H`` the posterior precision, so the constrained least squares under
   the pseudo-inertia LMI ``J(phi) >= eps E`` is exactly the weighted projection
   :func:`iem.physics.consistency.project` (a primal-dual interior-point method, checked against
   SLSQP and Clarabel in its tests): no separate convex-programming dependency.
7. **Uncertainty.** ``cov = H^-1`` (the lead marginalised out), ``std`` its diagonal's root,
   with the residual variance measured on the
   data and inflated by the residuals' own autocorrelation (filtered noise and model error are
   not white at 100 Hz: ``1 + 2 sum rho_k``). A parameter is *determined by the data* if its
   posterior std is below ``DATA_SHARE`` (a quarter) of its prior std, else *by the prior*.

Refusals (all :class:`IdentifyError`, so ``iem`` exits with status 2):

- :class:`MismatchedLogsError`: the two recordings are not the same motion (step 2).
- :class:`ExcitationError`: the motion does not determine each direction of the parameters to
  within ``excitation_tol`` (1 sigma; per group: mass 0.01 kg, first moments 0.002 kg·m,
  inertia 0.001 kg·m²), measured in the posterior covariance scaled by those tolerances; the
  message names the directions not excited and the parameters in them.
- :class:`BareLoadError`, the payload in the "bare" recording. The rule tests the loaded-minus-
  bare difference, not the bare recording against the nominal model alone (on a real arm the
  nominal model is off by 0.5-2 N·m, which a flange body can partly absorb):

  a. the difference carries no load: its mass is below ``min_mass`` (0.01 kg) or below 5
     standard deviations: the same load is in both recordings;
  b. the difference is not a rigid body: the unconstrained estimate lies more than
     ``BODY_SIGMAS`` (5) standard deviations (Mahalanobis, in ``H``) from the nearest
     consistent body, e.g. a negative mass or a negative inertia: the bare recording carries
     a load of its own that differs from the loaded one;
  c. the bare recording, against the nominal model, looks like a gross load at the flange:
     fitted alone it gives a consistent body of at least ``BARE_MASS`` (1 kg) that explains at
     least ``BARE_EXPLAINED`` (95 %) of the bare residual's power. Only a gross load, because
     a real arm's own model error looks partly like a flange body: on the simulated Panda,
     random link errors (mass ±5 %, CoM ±5 mm, inertia ±10 %) with friction and offsets read
     as 0.02-0.2 kg explaining 13-70 % of the residual, but every link 5 % heavier (2 N·m of
     residual, the top of a real Panda's 0.5-2 N·m) reads as 0.43-0.51 kg explaining 90 %,
     and 8 % heavier as 0.71 kg explaining 95 %. This rule catches a different, lighter tool
     left on the flange for the bare recording, which (a) and (b) cannot see when the
     difference of the two happens to be a rigid body. Its figures are always in the report
     (``bare_flange_mass_kg``, ``bare_flange_explained``).

The package, one step or concern a module: :mod:`.method` (:func:`identify`, steps 1, 3, 5-7),
:mod:`.fit` (the equations and their robust weighted least squares, step 4), :mod:`.refusals`
(the errors, the alignment of step 2 and the rules that refuse), :mod:`.result`
(:class:`Identification`). It imports numpy alone at import (so that the cell PC's
``iem identify`` starts without the simulator); scipy and Pinocchio (through
:mod:`sim.robot`) are imported when :func:`identify` runs.
"""

from iem.signals.recording import Recording, as_recording

from .fit import HUBER
from .method import CUTOFF_HZ, DATA_SHARE, EDGE_S, LEAD_PRIOR_S, RATE_HZ, identify
from .refusals import (
    BARE_EXPLAINED,
    BARE_MASS,
    BODY_SIGMAS,
    EXCITATION_TOL,
    MIN_MASS,
    MIN_OVERLAP_S,
    PATH_TOL,
    BareLoadError,
    ExcitationError,
    IdentifyError,
    MismatchedLogsError,
)
from .result import Identification

__all__ = ["BARE_EXPLAINED", "BARE_MASS", "BODY_SIGMAS", "CUTOFF_HZ", "DATA_SHARE", "EDGE_S",
           "EXCITATION_TOL", "HUBER", "LEAD_PRIOR_S", "MIN_MASS", "MIN_OVERLAP_S", "PATH_TOL",
           "RATE_HZ", "BareLoadError", "ExcitationError", "Identification", "IdentifyError",
           "MismatchedLogsError", "Recording", "as_recording", "identify"]
