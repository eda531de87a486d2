"""Calibrating the arm: its departure from the nominal model, from bare-arm traffic.

Model of the measured link-side torque of the bare arm (no payload)::

    tau_J = W(q, dq, ddq) theta + tau_f(dq; phi) + offset + noise

``W`` is Pinocchio's joint-torque regressor (``computeJointTorqueRegressor``, 7 x 70: ten
dynamic parameters per joint body), ``theta`` the bodies' parameters, ``tau_f`` the arm's
friction (:func:`sim.friction.friction_torque`: Gaz's Coulomb sigmoid, viscous and Stribeck
friction, per direction of motion; nine parameters per joint) and ``offset`` one constant
per torque sensor.

Steps (:func:`calibrate`):

1. **Signals.** The one offline signal chain of :mod:`iem.signals.offline`, which ``iem
   identify`` uses too: the traffic split where it has gaps of more than 50 ms (pieces
   shorter than ``4 trim_s + 2`` s left out), interpolated onto a uniform grid where its
   time steps jitter, spikes replaced, ``q``, ``dq`` and ``tau`` through the same
   4th-order Butterworth forwards and backwards (``cutoff_hz``), ``ddq`` the central
   difference of the filtered ``dq`` on the time stamps; then decimated to ``rate_hz``
   (100 Hz), the first and last ``trim_s`` of each piece dropped
   (:func:`.signals.calibration_signals`).
2. **Base parameters.** Only combinations of ``theta`` act on the torques. Column-pivoted QR
   of the regressor at random states, with a relative tolerance (:data:`QR_TOL`), gives their
   number and a basis; the excitation's condition number is that of the recorded regressor on
   this basis (and on the Coulomb and viscous friction's and the offsets' columns; the
   Stribeck part, seen only near zero speed, is left to its prior where the motion does not
   show it), each column scaled by its prior standard deviation, so that it measures the
   motion, not the units.
3. **Refusal.** A joint that barely moves (range under :data:`MIN_RANGE`, or speed under
   :data:`MIN_SPEED` in either direction: friction needs both signs) or a condition number
   above :data:`MAX_CONDITION` is refused with :class:`CalibrationError`, naming the joints
   and the parameter directions the motion does not see.
4. **Fit: maximum a posteriori, by Levenberg-Marquardt.** A prior centred on the nominal
   model (``theta``: the bounds of a few-percent link error, :func:`link_prior_std`;
   friction, :func:`friction_prior`: Gaz's values with half their size as standard
   deviation, no viscous friction +- 0.2 N·m·s/rad, no Stribeck excess +- 0.2 N·m at
   0.1 +- 0.1 rad/s; offsets 0 +- 0.5 N·m) regularises the least squares, so the
   directions the motion does not excite stay nominal and the excited ones follow the data.
   Friction is non-linear in ``phi2, phi3`` and the Stribeck velocities: each iteration
   linearises it at the current parameters (:func:`sim.friction.friction_jacobian`) and solves
   the damped linear MAP problem for all unknowns at once (70 + 63 + 7); a step is taken
   only if it lowers the posterior's cost, the damping grows until one does (Nielsen's
   rule), and the friction stays inside :data:`FRICTION_BOUNDS` (:func:`.fit.fit_map`). (The
   exact model is fitted, not a fixed-shape linearisation: Gaz's ``phi2`` differ by a
   factor of 3 between joints. Undamped Gauss-Newton on Gaz's sigmoid alone diverged on an
   arm with viscous friction and left a joint worse than the nominal model.)
5. **Physical consistency.** Each body's pseudo-inertia must be positive definite. The
   fit is moved to the consistent parameters nearest it in the metric of its own posterior
   precision (:func:`consistent_map`: the MAP under the pseudo-inertia LMIs, a small
   semidefinite program solved by Clarabel through cvxpy), so it moves mostly along the
   directions the data do not see and the torques barely change. Should the solver fail, a
   body still inconsistent is moved back toward its nominal values (a convex set holds both)
   just far enough (:func:`consistent`), which the report names.
6. **Never worse than nominal** (:func:`never_worse`). Per joint, the residual RMS of the
   result on the fitted signals is compared with the nominal model's; a joint that fits
   worse has its friction and offset refitted alone, and if the bodies are to blame the
   bodies stay nominal (the report's ``fallback_joints`` and warnings say so).
7. **Payload check.** A payload on the flange acts like extra mass on body 7: if the fit
   makes body 7 heavier than its prior allows (:data:`PAYLOAD_WARN_SIGMAS` standard
   deviations, at least :data:`PAYLOAD_WARN_KG`), the result carries a warning.

The result is a :class:`sim.arm.ArmParams` with a ``(7, 9)`` friction array whose
``report`` holds the per-joint residual RMS before (nominal model) and after, the condition
number, the number of base parameters, the iterations, the joints the guard changed and any
warnings.

The package, one step or concern a module: :mod:`.prior` (the settings and the prior, step
4's), :mod:`.signals` (step 1), :mod:`.excitation` (steps 2-3), :mod:`.fit` (steps 4 and 6),
:mod:`.consistency` (step 5), :mod:`.method` (:func:`calibrate`, the steps in order, step 7).
"""

from .consistency import consistent, consistent_map
from .excitation import (
    MAX_CONDITION,
    MIN_RANGE,
    MIN_SPEED,
    PARAM_NAMES,
    QR_TOL,
    base_basis,
    check_excitation,
)
from .fit import AMPLITUDES, never_worse
from .method import (
    PAYLOAD_WARN_KG,
    PAYLOAD_WARN_SIGMAS,
    calibrate,
    calibrate_segments,
    residual_rms,
)
from .prior import (
    FRICTION_BOUNDS,
    CalibrationError,
    CalibrationSettings,
    friction_prior,
    link_prior_std,
)
from .signals import JITTER_TOL, MAX_GAP_S, calibration_signals, segments

__all__ = ["AMPLITUDES", "FRICTION_BOUNDS", "JITTER_TOL", "MAX_CONDITION", "MAX_GAP_S",
           "MIN_RANGE", "MIN_SPEED", "PARAM_NAMES", "PAYLOAD_WARN_KG", "PAYLOAD_WARN_SIGMAS",
           "QR_TOL", "CalibrationError", "CalibrationSettings", "base_basis", "calibrate",
           "calibrate_segments", "calibration_signals", "check_excitation", "consistent",
           "consistent_map", "friction_prior", "link_prior_std", "never_worse",
           "residual_rms", "segments"]
