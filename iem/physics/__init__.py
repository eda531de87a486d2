"""IEM+phys: the incremental ensemble as a prior, Bayesian least squares on the physics.

The modules: the estimator (:mod:`~iem.physics.model`, :class:`PhysicsInformedEnsemble`), when
its heavy work is done (:mod:`~iem.physics.scheduler`, with a live link's spread projection
:mod:`~iem.physics.live_projection`) and what its model file holds
(:mod:`~iem.physics.state`); how it follows the payload (:mod:`~iem.physics.tracking`);
the equations (:mod:`~iem.physics.regression`, with the arm's
own noise :mod:`~iem.physics.torque_noise`), the prior (:mod:`~iem.physics.ensemble_prior`,
:mod:`~iem.physics.prior_summary`), the posterior (:mod:`~iem.physics.posterior`), physical
consistency (:mod:`~iem.physics.consistency`), the equations' test and the change detector
(:mod:`~iem.physics.innovation`, :mod:`~iem.physics.change`) and the small solves
(:mod:`~iem.physics.small_linalg`). LS (:mod:`iem.baselines.least_squares`) forms its
equations here too.

The paper's learners see one instant at a time and know no physics; least squares knows the
physics but needs rich motion and time. This model keeps both, per estimate:

- **The ensemble** (:class:`iem.ensemble.IncrementalEnsemble`, held, not copied): the same
  bags, learners and ``learn_one``, so it never forgets. Its instantaneous estimate at every
  sample is the evidence the robot's motion need not provide.
- **The prior** is a summary of the ensemble's estimates since the last payload change
  (:class:`iem.physics.prior_summary.PriorSummary`): their running mean ``mu_p``, with the
  covariance ``C_p`` = the mean, over those samples, of the covariance of the estimating
  bag's learner's error, plus the mean's own noise: the scatter of the estimates divided by
  their number (shrunk toward the sensor noise's share while there are few). A bag's error
  covariance (:class:`iem.physics.prior_summary.BagCalibration`) is measured on what the
  model has: the tandem samples of the training payloads at the bag's points, noise-free
  inputs, learner output minus true phi (:meth:`PhysicsInformedEnsemble.fit` for the initial
  bags, every learnt point for new ones). ``prior_scale`` multiplies its standard
  deviations. An estimate whose input lies beyond its bag's training distribution (the
  ensemble's ``ood_score`` above its threshold, e.g. a pose met at other velocities) adds
  its bag's covariance times ``(score / threshold)²``: the prior is less sure there, and the
  physics governs. The calibration holds where the learners were trained; far from that an
  ensemble can be off by more than it says, so the data judge the prior: its covariance is
  scaled by the empirical-Bayes factor ``s² >= 1`` that makes the data most likely
  (:func:`prior_inflation`), 1 while they agree.
- **The data**: the regression equations ``r = Y phi + e``, ``e ~ N(0, R)`` of
  :class:`iem.physics.regression.PayloadRegression`: the samples are averaged in blocks of
  ``update_every`` (one addition per sample), the block means go through the ``cutoff_hz``
  low-pass at the block rate (100 Hz by default), ddq is the difference of the filtered dq,
  ``R`` the torque noise plus the ddq noise through the arm's and the payload's inertia (at
  the block rate: the block mean has ``1 / update_every`` of the sample noise's variance);
  one equation per block after the filter has settled, kept in information form since the
  last change (:class:`iem.physics.posterior.EquationWindow`): ``Lambda_d = sum Y^T (c R)^-1
  Y``, ``eta_d = sum Y^T (c R)^-1 r``. Equations at 100 Hz of a 4 Hz low-pass are not
  independent: ``c`` (11.3 by default) is the sum of the filtered noise's autocorrelation at
  the equations' spacing (:func:`iem.physics.regression.correlation_weight`), so the
  window's information about a constant payload is what the independent information in the
  signal is, no more.
- **The posterior** (:class:`iem.physics.posterior.Posterior`): precision ``Lambda = C_p^-1
  + Lambda_d``, mean ``phi = Lambda^-1 (C_p^-1 mu_p + eta_d)``, ``std =
  sqrt(diag(Lambda^-1))``; the mean is then projected onto physically consistent parameters
  in the metric ``Lambda`` (:func:`iem.physics.consistency.project`), so the least certain
  parameters move the most. It is refreshed every ``refresh_every`` equations (20 Hz by
  default: the output smoothing's time constant is 0.2 s), and between refreshes every
  estimate is the cached one.
- **Payload change**: each equation's innovation, whitened by its covariance ``R + Y
  Lambda^-1 Y^T``, feeds a CUSUM (:class:`iem.physics.change.ChangeDetector`), beside the
  same innovation judged with the filtered equation's model error (:data:`MODEL_ERROR_GAIN`;
  the CUSUM adds the smaller of the two), from the window's :data:`DETECT_AFTER`-th equation
  on (before, a conflict is the prior's, which the inflation resolves, not a new payload's).
  On a change the data window, the prior summary and the detector restart, the equations of
  the next ``holdoff_s`` are skipped (the filter still holds the old payload's torque), and
  the estimate of that sample carries ``extra = {"change": True, "reset": True}`` so the
  caller restarts its smoothing (:class:`iem.online.OnlineIdentifier` does).
- **Before the physics, no smoothing**: until the regression's first equation after a start
  or a change (its filter settles for about 0.3 s), an estimate is the prior alone, the mean
  of the ensemble's estimates since then. Those estimates, and the first whose posterior
  holds an equation, carry ``extra = {"reset": True}``: the caller's smoothing restarts at
  each, so it adds no lag to what is already a mean, and starts from the physics instead of
  averaging it with the prior's estimates (at the demo's start the ensemble reads 1.44 kg
  for 1.615 over that 0.3 s, and the smoothing had carried its first, lower, readings on for
  about 0.6 s more).

**What the data do not determine**: an estimate's ``determined`` leaves out the parameter
groups (``mass``, ``com``, ``inertia``) for which the window's equations alone say less than
the prior (a short or slow motion hardly sees the inertia): those come from the prior, and
the safety gate says so when it writes them.

``observe_one(x, flange)`` does everything but train the ensemble: the payload part of
``learn_one`` for a frozen model (the benchmark's runs on the ensemble's own training path).
``reset()`` forgets the payload (a new task), never the ensemble; ``resume()`` restarts only
the regression's filter (the signal stream was interrupted, the payload stays).
"""

from .change import ChangeDetector
from .consistency import EPS, is_consistent, project
from .ensemble_prior import EnsemblePrior
from .innovation import MODEL_ERROR_GAIN, NIS_WINDOW, InnovationTest
from .model import PhysicsInformedEnsemble
from .posterior import DEFAULT_PRIOR_STD, EquationWindow, Posterior, combine, prior_inflation
from .prior_summary import BagCalibration, PriorSummary
from .regression import PayloadRegression, load_dynamics, required_dynamics
from .scheduler import LIVE_PROJECT_BUDGET, SPREAD_WAIT, RefreshScheduler
from .torque_noise import NOMINAL_ARM_NOISE, TorqueNoise
from .tracking import DETECT_AFTER, PRIOR_FLOOR

__all__ = ["DEFAULT_PRIOR_STD", "DETECT_AFTER", "EPS", "LIVE_PROJECT_BUDGET",
           "MODEL_ERROR_GAIN", "NIS_WINDOW", "NOMINAL_ARM_NOISE", "PRIOR_FLOOR", "SPREAD_WAIT",
           "BagCalibration", "ChangeDetector", "EnsemblePrior", "EquationWindow",
           "InnovationTest", "PayloadRegression", "PhysicsInformedEnsemble", "Posterior",
           "PriorSummary", "RefreshScheduler", "TorqueNoise", "combine", "is_consistent",
           "load_dynamics", "prior_inflation", "project", "required_dynamics"]
