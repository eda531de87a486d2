"""IEM+phys: the Bayesian update against batch least squares, the regression against
Pinocchio, the prior against the ensemble it summarises, the change detector in simulation.

Hand-made data use a linear "robot" (:func:`linear_dynamics`): no arm torque, no arm inertia,
and a regressor linear in q, so the low-pass commutes with it and every equation is exact.
"""

import numpy as np
import pinocchio as pin
import pytest

from iem.base import BaseEstimator
from iem.baselines.least_squares import RecursiveLeastSquares
from iem.errors import InvalidInputError
from iem.factories import register_factory
from iem.online import OnlineIdentifier
from iem.physics import MODEL_ERROR_GAIN, PRIOR_FLOOR, PhysicsInformedEnsemble, prior_inflation
from iem.physics.change import ChangeDetector, chi_square
from iem.physics.consistency import is_consistent, project
from iem.physics.posterior import DEFAULT_PRIOR_STD
from iem.physics.regression import PayloadRegression, impulse_response, noise_gains, settle_samples
from iem.signals.filters import LowPass2
from iem.signals.gaps import RESTART
from iem.types import JointState, PayloadEstimate
from sim.arm import NOMINAL_DYNAMICS
from sim.family import test_payloads
from sim.robot import ArmModel

from .test_checks import DATA

_RNG = np.random.default_rng(11)
_Y0 = _RNG.normal(0.0, 3.0, (7, 10))
_YQ = _RNG.normal(0.0, 3.0, (7, 7, 10))
FAKE = f"{__name__}:linear_dynamics"
register_factory(FAKE)  # a model may name it (iem.factories)
PHI = test_payloads()["test-3w"].to_phi()


def linear_dynamics():
    """``f(q, dq, ddq) -> (0, Y0 + sum_j q_j Yq_j, 0)``: exact under any linear filter."""
    def f(q, dq, ddq):
        return np.zeros(7), _Y0 + np.einsum("j,jrc->rc", q, _YQ), np.zeros((7, 7))
    return f


def _hand_made(n: int, seed: int = 0):
    """Measured samples of the linear robot carrying PHI, torque noise 0.05 N·m."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 1000.0
    q = 0.5 * np.sin(2 * np.pi * np.outer(t, rng.uniform(0.2, 1.0, 7)) + rng.uniform(0, 6, 7))
    f = linear_dynamics()
    tau = np.array([f(qk, None, None)[1] @ PHI for qk in q])
    tau += rng.normal(0.0, 0.05, tau.shape)
    return np.hstack((q, np.zeros_like(q), tau))


# -- the Bayesian update ---------------------------------------------------------------
def test_information_form_equals_batch_weighted_least_squares():
    """Step by step, the model's posterior is the weighted least-squares solution of the
    prior plus every equation so far (each weighted by its R times the correlation factor),
    and the Kalman form of LS fed the same equations agrees."""
    X = _hand_made(1500)
    # untrained: weak prior; the posterior refreshed at every equation, to compare each
    model = PhysicsInformedEnsemble(dynamics=FAKE, rate_hz=1000.0, update_every=10,
                                    point_frames=1,
                                    refresh_every=1)
    twin = PayloadRegression(FAKE, cutoff_hz=4.0, every=1, settle=-1, decimate=10)
    c = twin.correlation_weight
    prior_cov = np.diag(np.square(DEFAULT_PRIOR_STD) + np.square(PRIOR_FLOOR))
    kalman = RecursiveLeastSquares(NOMINAL_DYNAMICS, prior_std=np.sqrt(np.diag(prior_cov)))
    rows, rhs = [np.linalg.cholesky(np.linalg.inv(prior_cov)).T], [np.zeros(10)]
    checked = 0
    for k, x in enumerate(X):
        model.observe_one(x, None)
        eq = twin(x)
        if eq is None:
            continue
        Y, r, R = eq
        w = np.linalg.cholesky(np.linalg.inv(c * R)).T  # w^T w = (c R)^-1
        rows.append(w @ Y)
        rhs.append(w @ r)
        kalman.update(Y, r, c * R)
        if len(rows) % 10 == 2 or k == len(X) - 1:
            A, b = np.vstack(rows), np.concatenate(rhs)
            batch = np.linalg.lstsq(A, b, rcond=None)[0]
            batch_cov = np.linalg.inv(A.T @ A)
            mean, cov = model.posterior()
            np.testing.assert_allclose(mean, batch, rtol=1e-6, atol=1e-9)
            np.testing.assert_allclose(cov, batch_cov, rtol=1e-6, atol=1e-15)
            np.testing.assert_allclose(kalman.phi, batch, rtol=1e-5, atol=1e-8)
            checked += 1
    assert checked >= 10 and model.changes == 0 and model.prior_inflation == 1.0
    # and the equations were enough to find the payload
    mean, cov = model.posterior()
    assert np.all(np.abs(mean - PHI) < 4 * np.sqrt(np.diag(cov)))


def test_estimate_is_the_projected_posterior_with_its_std():
    X = _hand_made(600)
    model = PhysicsInformedEnsemble(dynamics=FAKE, rate_hz=1000.0, update_every=10, point_frames=1)
    for x in X:
        model.observe_one(x, None)
    est = model.predict_one(X[-1], None, t=0.6)
    mean, cov = model.posterior()
    np.testing.assert_allclose(est.std, np.sqrt(np.diag(cov)))
    np.testing.assert_allclose(est.phi, project(mean, np.linalg.inv(cov)), rtol=1e-9)
    # the first estimate with equations restarts the smoothing; the next says only its NIS
    assert is_consistent(est.phi) and est.t == 0.6 and set(est.extra) == {"reset", "mean_mass"}
    assert est.extra["mean_mass"] == mean[0]  # before the projection
    assert set(model.predict_one(X[-1], None).extra) == {"mean_mass"}
    assert 0.0 < est.nis < 3.0  # the hand-made data fit the model
    assert est.ood is False and est.std is not None  # what the gate needs, reported


# -- the regression ----------------------------------------------------------------------
def test_payload_mass_matrix_is_pinocchios():
    """``M_p``, from the regressor (generic) and from ``J^T I J`` (the Panda's fast path),
    equals CRBA with the payload minus CRBA without."""
    model = ArmModel()
    fast = PayloadRegression(NOMINAL_DYNAMICS)
    generic = PayloadRegression(NOMINAL_DYNAMICS)
    f = fast.model()
    generic._f = lambda q, dq, ddq: f(q, dq, ddq)  # no payload_mass_matrix method
    rng = np.random.default_rng(3)
    for _ in range(5):
        q, dq, ddq = model.random_state(rng, margin=0.1)
        _, Y, M = f(q, dq, ddq)
        model.rnea_with_payload(q, dq, ddq, PHI)  # loads PHI into the payload model
        M_with = pin.crba(model._pl_model, model._pl_data, q)
        M_with = np.triu(M_with) + np.triu(M_with, 1).T
        for reg in (fast, generic):
            Mp = reg.payload_mass_matrix(q, dq, ddq, Y, PHI)
            np.testing.assert_allclose(Mp, M_with - M, atol=1e-9)


def test_the_arm_dynamics_give_the_payload_mass_matrix_without_the_regressor():
    """The arm's dynamics (nominal or a calibrated arm) give ``M_p`` from one Jacobian: the
    regression never calls them seven times more (each an RNEA, the friction and a CRBA)."""
    from sim.arm import ArmDynamics, ArmParams

    class Counted(ArmDynamics):
        calls = 0

        def __call__(self, q, dq, ddq):
            self.calls += 1
            return super().__call__(q, dq, ddq)

    rng = np.random.default_rng(5)
    nominal = ArmParams.nominal(None)
    calibrated = ArmParams(nominal.link_params, rng.uniform(0.1, 1.0, (7, 3)),
                           rng.normal(0.0, 0.1, 7), {})
    model = ArmModel()
    for arm in (None, calibrated):
        reg = PayloadRegression(NOMINAL_DYNAMICS)
        reg._f = dynamics = Counted(arm)
        q, dq, ddq = model.random_state(rng, margin=0.1)
        _, Y, _ = dynamics(q, dq, ddq)
        dynamics.calls = 0
        Mp = reg.payload_mass_matrix(q, dq, ddq, Y, PHI)
        assert dynamics.calls == 0
        model.rnea_with_payload(q, dq, ddq, PHI)  # the nominal links: M_p is the same
        M_with = pin.crba(model._pl_model, model._pl_data, q)
        M_nominal = pin.crba(model.model, model.data, q)
        np.testing.assert_allclose(Mp, np.triu(M_with - M_nominal)
                                   + np.triu(M_with - M_nominal, 1).T, atol=1e-9)


def test_settle_is_where_the_first_samples_noise_has_decayed():
    for fc in (4.0, 20.0):
        n = settle_samples(fc, 1000.0, tol=0.1)
        gain, dgain = noise_gains(fc, 1000.0)
        h = impulse_response(fc, 1000.0)
        assert np.abs(1.0 - np.cumsum(h)[n:]).max() <= 0.1 * np.sqrt(gain)
        assert np.abs(h[n:n + 2000]).max() * 1000.0 <= 0.1 * np.sqrt(dgain)
        assert n > 0 and settle_samples(fc, 1000.0, tol=0.5) < n


def test_noiseless_equations_hold_on_the_task_path(new_rollout_noiseless):
    """Same lag on both sides: without noise the 4 Hz equations fit the true payload to a
    small fraction of the noise they are weighted for."""
    ro = new_rollout_noiseless
    reg = PayloadRegression(NOMINAL_DYNAMICS, cutoff_hz=4.0, every=10, settle=-1,
                            payload_inertia=True)
    worst = 0.0
    for x in ro.features:
        eq = reg(x, PHI)
        if eq is not None:
            Y, r, R = eq
            worst = max(worst, chi_square(r - Y @ PHI, R))
    assert worst < 0.1  # chi-square of 7 unit-variance terms would be about 7


def test_the_curvature_is_the_second_difference_of_the_robot_torque(new_rollout_noiseless):
    """Every equation's ``curvature`` is ``tau_robot`` of the last three equations, second
    difference, each ``tau_robot`` recomputed with Pinocchio at the equation's filtered
    state; None for the first two and again after a restart."""
    from sim.arm import arm_dynamics

    dyn = arm_dynamics()
    reg = PayloadRegression(NOMINAL_DYNAMICS, cutoff_hz=4.0, every=1, settle=-1,
                            payload_inertia=True, decimate=10)
    taus, seen = [], 0
    for k, x in enumerate(new_rollout_noiseless.features[:3000]):
        if k == 2000:
            reg(x, PHI, steps=RESTART)
            taus = []
            assert reg.curvature is None
            continue
        prev = reg._lp._y
        eq = reg(x, PHI)
        if eq is None:
            continue
        f, p = reg._lp._y, prev
        mid = 0.5 * (f + p)
        taus.append(dyn(mid[:7], mid[7:14], (f[7:14] - p[7:14]) * reg.filter_rate_hz)[0])
        if len(taus) < 3:
            assert reg.curvature is None
        else:
            np.testing.assert_allclose(reg.curvature, taus[-1] - 2 * taus[-2] + taus[-3],
                                       atol=1e-12)
            seen += 1
    assert seen > 100


def test_the_detector_gets_the_equation_with_and_without_its_model_error_the_nis_without():
    """``_test`` (:class:`iem.physics.innovation.InnovationTest`): the detector gets ``nu^T S^-1
    nu`` and ``nu^T (S + diag((g c)^2))^-1 nu``, the NIS the first over 7, ``S = R + Y P Y^T``
    (numpy's own solve here); without a curvature (the first equations) the plain one alone."""
    X = _hand_made(1500)
    rng = np.random.default_rng(4)
    Y, R = rng.normal(size=(7, 10)), np.diag(rng.uniform(0.01, 0.05, 7) ** 2)
    r, c = Y @ PHI + rng.normal(0.0, 0.3, 7), rng.normal(0.0, 0.1, 7)
    seen = []
    model = PhysicsInformedEnsemble(dynamics=FAKE, rate_hz=1000.0, update_every=10, point_frames=1)
    for x in X:
        model.observe_one(x, None)
    model._innovation.detector = type("Spy", (ChangeDetector,), {
        "__call__": lambda self, a, b=None: seen.append((a, b)) or False})()
    mean, cov = model.posterior()
    S = R + Y @ cov @ Y.T
    nu = r - Y @ mean
    plain = float(nu @ np.linalg.solve(S, nu))
    judged = float(nu @ np.linalg.solve(S + np.diag((MODEL_ERROR_GAIN * c) ** 2), nu))
    model._test(Y, r, R, c)
    model._test(Y, r, R, None)
    assert model._innovation.last_nis == pytest.approx(plain / 7.0, rel=1e-9)
    assert seen[0] == pytest.approx((plain, judged), rel=1e-9) and judged < plain
    assert seen[1][0] == pytest.approx(plain, rel=1e-9) and seen[1][1] is None


@pytest.fixture(scope="module")
def new_rollout_noiseless():
    from sim.paths import new_task_path
    from sim.plant import ArmPlant, SensorModel

    payload = test_payloads()["test-3w"]
    plant = ArmPlant(payload=payload, sensor=SensorModel.noiseless(), controller_load=payload)
    return plant.follow(new_task_path())


# -- the prior -----------------------------------------------------------------------------
def _trained(dynamics=FAKE, **kw):
    model = PhysicsInformedEnsemble(
        ensemble={"seed": 0, "fit_epochs": 2, "warmup_iters": 10, "iters": 2},
        dynamics=dynamics, **kw)
    idx = np.asarray(DATA.fit_points)
    model.fit(DATA.X[idx, :7], DATA.F[idx], lambda i: DATA.samples_at(int(idx[i])))
    return model


def test_prior_is_the_mean_of_the_ensembles_estimates():
    model = _trained(update_every=1)
    ens = model.ensemble_model
    est = [ens.predict_one(x, f) for x, f in zip(DATA.X[:50], DATA.F[:50], strict=True)]
    for x, f in zip(DATA.X[:50], DATA.F[:50], strict=True):
        model._reg.count = -10**9  # keep the regression from forming equations
        model.observe_one(x, f)
    mean, cov = model.posterior()
    np.testing.assert_allclose(mean, np.mean([e.phi for e in est], axis=0), rtol=1e-9)
    bag_cov = np.mean([model.ensemble_prior.bag_cov(e.bag) for e in est], axis=0)
    assert np.all(np.diag(cov) >= np.diag(bag_cov))  # at least the learners' error spread


def test_bag_covariance_is_the_learners_error_on_its_samples():
    model = _trained()
    ens = model.ensemble_model
    bag = 0
    labels = ens.router.route_many(DATA.X[DATA.fit_points, :7], DATA.F[DATA.fit_points])
    pts = [p for p, b in zip(DATA.fit_points, labels, strict=True) if b == bag]
    pts = pts[:: ens.fit_stride]
    errs = np.vstack([ens.learner(bag).predict_many(DATA.samples_at(p)[0])
                      - DATA.samples_at(p)[1] for p in pts])
    np.testing.assert_allclose(model.ensemble_prior.bag_cov(bag), errs.T @ errs / len(errs),
                               rtol=1e-9)


def test_learnt_points_calibrate_the_prior_as_inline_with_the_learning_in_the_worker():
    """In the background the learnt points' samples and errors are made in the worker and
    the bag covariances updated in the cycle as they land: after the same points, drained,
    the covariances are the inline ones."""
    inline, back = _trained(), _trained()
    back.ensemble_model.set_background(True)
    count = {"inline": 0, "back": 0}
    for name, model in (("inline", inline), ("back", back)):
        for i in DATA.train_points():
            def samples(i=i, name=name):
                count[name] += 1
                return DATA.samples_at(i)
            model.learn_one(DATA.X[i], DATA.F[i], samples)
            if name == "back":
                model.ensemble_model.drain()
        model.ensemble_prior.calibrate_trained()
    assert count["inline"] == count["back"] > 3
    for bag in range(inline.n_bags):
        assert inline.ensemble_prior.calib.measured(bag) == back.ensemble_prior.calib.measured(
            bag)
        if inline.ensemble_prior.calib.measured(bag):
            np.testing.assert_array_equal(back.ensemble_prior.bag_cov(bag),
                                          inline.ensemble_prior.bag_cov(bag))
    back.ensemble_model.stop()


def test_prior_inflation_is_the_maximum_likelihood_scale():
    """1 while the data agree with the prior; the likelihood's maximiser (checked on a grid)
    when they show the prior's mean far off."""
    rng = np.random.default_rng(5)
    A = rng.normal(size=(30, 10))
    info = A.T @ A * 1e4  # sharp data in every direction
    c_p = np.diag(rng.uniform(0.5, 2.0, 10)) * 1e-2
    truth = rng.normal(size=10)
    eta = info @ truth + np.linalg.cholesky(info) @ rng.normal(size=10)
    agree = truth + np.linalg.cholesky(c_p) @ rng.normal(size=10) * 0.5
    assert prior_inflation(agree, c_p, info, eta) == 1.0
    far = truth + np.linalg.cholesky(c_p) @ rng.normal(size=10) * 20.0
    s2 = prior_inflation(far, c_p, info, eta)
    v = eta - info @ far

    def loglik(s2):
        cov = info + s2 * info @ c_p @ info
        return -0.5 * (np.linalg.slogdet(cov)[1] + v @ np.linalg.solve(cov, v))

    grid = np.exp(np.linspace(0.0, np.log(1e5), 2001))
    best = grid[np.argmax([loglik(g) for g in grid])]
    assert 100 < s2 < 1e4 and s2 == pytest.approx(best, rel=0.01)
    assert prior_inflation(far, c_p, np.zeros((10, 10)), np.zeros(10)) == 1.0  # no data


def test_a_wrong_prior_is_inflated_until_the_data_agree():
    """An ensemble whose estimates are 0.3 kg off (far outside its calibration): the data
    inflate the prior, and the posterior's error stays within its reported uncertainty."""
    X = _hand_made(3000)
    model = _trained(rate_hz=1000.0, update_every=10, point_frames=1)
    bias = np.zeros(10)
    bias[0], bias[4:] = 0.3, 3e-3
    ens = model.ensemble_model
    real = ens.predict_one

    def off(x, flange, t=0.0):
        est = real(x, flange, t)
        return PayloadEstimate(t=t, phi=PHI + bias, bag=est.bag)

    ens.predict_one = off
    for x, f in zip(X, DATA.F[np.arange(len(X)) % DATA.n], strict=True):
        model.observe_one(x, f)
    mean, cov = model.posterior()
    assert model.prior_inflation > 100 and model.changes == 0  # no payload change either
    assert np.all(np.abs(mean - PHI) < 3 * np.sqrt(np.diag(cov)))


def test_the_prior_alone_and_the_first_estimate_with_equations_restart_the_smoothing():
    """Until the regression's first equation, IEM+phys shows the ensemble's summary alone,
    already a mean: each such estimate, and the first whose posterior holds equations, says
    ``reset`` (the caller's smoothing restarts there), none after it, for each payload; a
    copy restored from its state does not say it again."""
    X = _hand_made(900)
    F = DATA.F[np.arange(len(X)) % DATA.n]
    model = _trained(rate_hz=1000.0, update_every=10, point_frames=1)
    for task in range(2):
        resets, equations = [], []
        for x, f in zip(X, F, strict=True):
            model.observe_one(x, f)
            est = model.predict_one(x, f)
            resets.append(bool(est.extra.get("reset")))
            equations.append(model._posterior().equations)
        first = equations.index(next(m for m in equations if m > 0))
        assert first >= model._reg.settle * model._reg.decimate  # the prior alone till it settled
        assert resets == [k <= first for k in range(len(X))], task
        model.reset()  # a new task: its payload's first equation restarts the smoothing too
    for x, f in zip(X[:400], F[:400], strict=True):
        model.observe_one(x, f)
        model.predict_one(x, f)
    restored = PhysicsInformedEnsemble.from_state(model.to_state())
    assert restored._posterior().equations == model._posterior().equations > 0
    assert not any(restored.predict_one(x, f).extra.get("reset")
                   for x, f in zip(X[400:], F[400:], strict=True))


def test_a_posterior_saved_as_a_list_still_loads_and_its_size_is_what_it_holds():
    """Model files from before the posterior's state was a dict hold it as a list."""
    from iem.physics.posterior import Posterior

    post = Posterior(PHI.copy(), np.eye(10), np.eye(10), 2.0, equations=7)
    state = post.to_state()
    old = [state["mean"], state["cov"], state["precision"], state["inflation"]]
    for saved, equations in ((state, 7), (old, 3)):
        back = Posterior.from_state(saved, equations=3)
        np.testing.assert_array_equal(back.mean, PHI)
        assert back.inflation == 2.0 and back.equations == equations
    # phi and std are made on first use; the size a model reserves counts them
    held = (post.mean, post.cov, post.precision, post.phi, post.std, post.gain_var,
            post.arm_cov)
    assert Posterior.nbytes() == sum(a.nbytes for a in held)


def test_an_estimate_is_routed_by_the_samples_values_not_its_array():
    """``predict_one`` reuses the bag ``observe_one`` found only for the same values: a
    caller that refills one buffer with the next sample gets that sample's own bag."""
    model = _trained()
    router = model.ensemble_model.router

    def bag_of(x, f):
        inside, nearest = router.route(x[:7], f)
        return inside if inside >= 0 else nearest

    far_x, far_f = DATA.X[0].copy(), DATA.F[0] + 1.0
    far_x[:7] += 1.0  # far from the fitted bags: the ensemble starts a bag there
    model.ensemble_model.learn_one(far_x, far_f, DATA.samples_at(0))
    near = bag_of(DATA.X[0], DATA.F[0])
    far = bag_of(far_x, far_f)
    buf = DATA.X[0].copy()
    model.observe_one(buf, DATA.F[0])
    assert model.predict_one(buf.copy(), DATA.F[0]).bag == near  # a copy: the same bag
    buf[:] = far_x  # the same array, the next sample's values
    assert model.predict_one(buf, far_f).bag == far != near


def test_bad_parameters_are_errors():
    with pytest.raises(InvalidInputError, match="prior_scale"):
        PhysicsInformedEnsemble(dynamics=NOMINAL_DYNAMICS, prior_scale=0.0)
    with pytest.raises(InvalidInputError, match="21 values"):
        PhysicsInformedEnsemble(dynamics=NOMINAL_DYNAMICS).predict_one(np.zeros(7), None)


# -- the change detector -----------------------------------------------------------------
def test_cusum_accumulates_excess_and_forgets_quiet():
    # the CUSUM's own arithmetic, on the raw chi² (the level is tests/iem/test_change.py's)
    det = ChangeDetector(dof=7, drift=21.0, threshold=100.0, level_equations=0)
    assert not any(det(7.0) for _ in range(1000)) and det.g == 0.0
    assert not det(7.0 + 21.0 + 60.0) and det.g == pytest.approx(60.0)
    assert det(7.0 + 21.0 + 50.0)  # 110 > 100
    det.reset()
    assert det.g == 0.0 and not det(float("nan"))


@pytest.fixture(scope="module")
def switch_rollouts():
    """The new task path with test-3w, plain and with test-4w mounted at 3 s."""
    from sim.paths import new_task_path
    from sim.plant import ArmPlant

    path = new_task_path()
    p3, p4 = test_payloads()["test-3w"], test_payloads()["test-4w"]
    plain = ArmPlant(payload=p3, seed=5, controller_load=p3).follow(path)
    switched = ArmPlant(payload=p3, seed=5, controller_load=p3).follow(path,
                                                                         mount={3000: p4})
    return plain, switched


def _points(rollout) -> np.ndarray:
    """A 1 kHz rollout's block points (iem.signals.blocks: means of 10 frames), as the plug-in feeds
    the estimator: ``(n / 10, 21)``."""
    from iem.signals.blocks import BlockFormer

    return BlockFormer().push_many(rollout.t, rollout.features).X


def _changes(rollout) -> list[int]:
    """Block points at which the physics alone (no bags, the rated-payload prior) reports
    a change."""
    model = PhysicsInformedEnsemble(dynamics=NOMINAL_DYNAMICS)
    out = []
    for k, x in enumerate(_points(rollout)):
        model.observe_one(x, None)
        if model.predict_one(x, None).extra.get("change"):
            out.append(k)
    return out


def test_switch_between_test_payloads_is_detected_within_0_2_s(switch_rollouts):
    _, switched = switch_rollouts
    changes = _changes(switched)
    assert len(changes) == 1 and 300 <= changes[0] <= 320  # block points: 10 ms each


def test_no_false_alarm_with_a_fixed_payload(switch_rollouts):
    plain, _ = switch_rollouts
    assert _changes(plain) == []


def test_online_identifier_restarts_smoothing_on_reset_and_observes_when_frozen():
    class Toy(BaseEstimator):
        name = "toy"

        def __init__(self):
            self.observed = 0
            self.value = 0.0

        def learn_one(self, x, flange, samples):
            raise AssertionError("frozen: must not learn")

        def observe_one(self, x, flange):
            self.observed += 1

        def predict_one(self, x, flange, t=0.0):
            self.value = 1.0 if self.observed >= 3 else 0.0
            extra = {"reset": True} if self.observed == 3 else {}
            return PayloadEstimate(t=t, phi=np.full(10, self.value), extra=extra)

    toy = Toy()
    online = OnlineIdentifier(toy, lambda q: np.zeros(3), None, learn=False)
    outs = [online.step_block(JointState(t=k * 1e-2, q=np.zeros(7), dq=np.zeros(7),
                                         tau_J=np.zeros(7)))[1][0] for k in range(4)]
    assert toy.observed == 4
    assert outs[:2] == [0.0, 0.0] and outs[2] == 1.0 and outs[3] == 1.0  # no lag after reset


def test_online_identifier_resumes_the_stream_at_its_start_and_after_gaps():
    """The first sample, a silence longer than the state filter's max_gap_s and a time stamp
    going backwards each restart the signal filters (``resume``), never the payload."""
    class Toy(BaseEstimator):
        name = "toy"

        def __init__(self):
            self.resumed = []

        def resume(self):
            self.resumed.append(True)

        def learn_one(self, x, flange, samples):
            pass

        def predict_one(self, x, flange, t=0.0):
            return PayloadEstimate(t=t, phi=np.ones(10))

    toy = Toy()
    online = OnlineIdentifier(toy, lambda q: np.zeros(3), None)
    gap = online.state_filter.max_gap_s
    times = [0.0, 0.01, 0.02, 0.02 + 0.9 * gap, 0.02 + 3 * gap, 0.03 + 3 * gap, 0.01]
    counts = []
    for t in times:  # block points, 100 per second
        online.step_block(JointState(t=t, q=np.zeros(7), dq=np.zeros(7), tau_J=np.zeros(7)))
        counts.append(len(toy.resumed))
    assert counts == [1, 1, 1, 1, 2, 2, 3]
    online.reset()  # a new task restarts the stream too, from its next sample
    online.step_block(JointState(t=0.02, q=np.zeros(7), dq=np.zeros(7), tau_J=np.zeros(7)))
    assert len(toy.resumed) == 4


def test_resume_keeps_the_payload_and_restarts_only_the_filter():
    """A second recording of the same payload after ``resume``: no equation straddles the
    jump between the recordings (the filter settles again), no change is detected, the
    window keeps its equations and the posterior only sharpens."""
    first, second = _hand_made(1500, seed=0), _hand_made(1500, seed=1)
    model = PhysicsInformedEnsemble(dynamics=FAKE, rate_hz=1000.0, update_every=10, point_frames=1)
    for x in first:
        model.observe_one(x, None)
    m_before, (_, cov_before) = model._m, model.posterior()
    model.resume()
    settle = model._reg.settle
    for x in second[:settle]:
        model.observe_one(x, None)
    assert model._m == m_before  # the settling samples give no equations
    for x in second[settle:]:
        model.observe_one(x, None)
    mean, cov = model.posterior()
    assert model.changes == 0 and model._m > m_before
    # the data alone: the information form's own inverse, no prior
    np.testing.assert_allclose(model.data_std, np.sqrt(np.diag(np.linalg.inv(model._info))),
                               rtol=1e-6)
    assert np.all(np.isinf(PhysicsInformedEnsemble(dynamics=FAKE).data_std))
    assert np.all(np.diag(cov) <= np.diag(cov_before) * (1 + 1e-9))
    assert np.all(np.abs(mean - PHI) < 4 * np.sqrt(np.diag(cov)))
    ls = RecursiveLeastSquares(dynamics=FAKE)
    for x in first:
        ls.learn_one(x)
    phi, updates = ls.phi.copy(), ls.updates
    ls.resume()
    np.testing.assert_array_equal(ls.phi, phi)
    assert ls.updates == updates and ls._regression.count == 0


def test_lowpass_state_round_trips_through_the_regression_state():
    reg = PayloadRegression(NOMINAL_DYNAMICS, cutoff_hz=4.0)
    other = PayloadRegression(NOMINAL_DYNAMICS, cutoff_hz=4.0)
    rng = np.random.default_rng(0)
    for x in rng.normal(size=(10, 21)):
        reg._lp(x)
    other.set_state(reg.to_state())
    x = rng.normal(size=21)
    assert isinstance(other._lp, LowPass2)
    np.testing.assert_array_equal(reg._lp(x), other._lp(x))


def test_every_output_is_physically_consistent():
    """Thousands of estimates from junk (the check suite's synthetic path, whose torques are
    no Panda's, and random inputs): the raw posterior is often impossible, the output never."""
    from iem.physics.consistency import min_eigenvalue

    from .test_consistency import _payload_ok

    model = _trained(dynamics=NOMINAL_DYNAMICS)
    rng = np.random.default_rng(8)
    junk = DATA.X[rng.integers(0, DATA.n, 3000)] + rng.normal(0.0, 1.0, (3000, 21))
    flanges = DATA.F[rng.integers(0, DATA.n, 3000)]
    impossible = 0
    outputs = []
    for i, (x, f) in enumerate(zip(junk, flanges, strict=True)):
        if i % 2:
            model.learn_one(x, f, DATA.samples_at(i % DATA.n))
        else:
            model.observe_one(x, f)
        mean, _ = model.posterior(x, f)
        impossible += min_eigenvalue(mean) <= 0.0
        outputs.append(model.predict_one(x, f).phi)
    outputs = np.array(outputs)
    assert impossible > 300  # the projection had work to do
    assert all(is_consistent(phi) for phi in outputs)
    assert all(_payload_ok(phi) for phi in outputs[::10])


def test_an_input_beyond_its_bags_training_makes_the_prior_less_sure():
    """Issue 15: the ensemble's out-of-distribution score inflates the prior the estimate
    contributes by (score / threshold)², so the physics governs there."""
    model = _trained()
    ens = model.ensemble_model
    x, f = DATA.X[0].copy(), DATA.F[0]
    near = model._prior(x, f)
    bag = ens.router.route(x[:7], f)[0]
    far = x.copy()
    far[14:] += 40.0 * ens.learner(bag).scale[14:]  # torques far beyond the bag's training
    est = ens.predict_one(far, f)
    assert est.extra["ood_score"] > ens.ood_threshold
    _, cov_far = model._prior(far, f)
    factor = (est.extra["ood_score"] / ens.ood_threshold) ** 2
    assert np.all(np.diag(cov_far) >= 0.9 * factor * np.diag(model.ensemble_prior.bag_cov(est.bag)))
    assert np.trace(cov_far) > 10 * np.trace(near[1])


def test_a_prior_from_the_ensemble_carries_the_arms_leftover_and_a_payload_file_does_not():
    """The learners learnt on the arm model's simulations: on a calibrated arm their error is
    at least what the arm model's leftover reads as payload (the arm noise's ``bias_std``),
    so the ensemble's prior carries it on its diagonal, after the prior's scale; a payload
    started from a file keeps its own covariance, and an arm without a measured leftover
    leaves the ensemble's as it is."""
    from iem.physics.torque_noise import NOMINAL_ARM_NOISE

    bias = np.array([0.05, 0.01, 0.02, 0.03, 1e-3, 2e-3, 3e-3, 4e-3, 5e-3, 6e-3])
    plain = {**NOMINAL_ARM_NOISE.to_dict(), "bias_std": [0.0] * 10}
    with_bias = {**plain, "bias_std": bias.tolist()}
    x, f = DATA.X[0].copy(), DATA.F[0]
    mean0, cov0 = _trained(torque_noise=plain)._prior(x, f)
    model = _trained(torque_noise=with_bias)
    mean1, cov1 = model._prior(x, f)
    np.testing.assert_array_equal(mean1, mean0)
    np.testing.assert_allclose(cov1 - cov0, np.diag(bias ** 2), rtol=1e-9, atol=1e-15)
    phi, std = test_payloads()["test-3w"].to_phi(), np.full(10, 0.01)
    model.start_from(phi, std)
    started = _trained(torque_noise=plain)
    started.start_from(phi, std)
    np.testing.assert_allclose(model._prior()[1], started._prior()[1], rtol=1e-12)


def test_a_reused_slot_forgets_the_retired_bags_calibration():
    model = _trained()
    ens = model.ensemble_model
    before = model.ensemble_prior.bag_cov(0).copy()
    ens._gen[0] += 1  # the budget gave slot 0 to a new bag
    learner = ens.learner(0)
    default = np.diag(np.square((learner.hi - learner.lo) / 4.0))
    # unmeasured, not the old errors
    np.testing.assert_allclose(model.ensemble_prior.bag_cov(0), default)
    assert not np.allclose(before, default)


def _spread_run(model, X, F, monkeypatch):
    """Feed ``X`` sample by sample; per sample the heavy jobs done (equations formed,
    equations tested, posterior refreshes, Newton steps of the projection), every posterior
    made, and the estimates."""
    import iem.physics.live_projection as live
    import iem.physics.model as physics
    import iem.physics.tracking as tracking
    from iem.physics.regression import PayloadRegression as Reg

    jobs = {"formed": 0, "tested": 0, "refreshed": 0, "newton": 0}
    made = []
    filt, take, comb, steps = Reg._filter, PhysicsInformedEnsemble._take, physics.combine, \
        live.project_steps

    def counted_filter(self, *a, **k):
        out = filt(self, *a, **k)
        jobs["formed"] += out is not None
        return out

    def counted_take(self, equation):
        jobs["tested"] += 1
        return take(self, equation)

    def counted_combine(*a, **k):
        post = comb(*a, **k)
        jobs["refreshed"] += 1
        made.append(post)
        return post

    def counted_steps(*a, **k):
        gen = steps(*a, **k)
        while True:
            try:
                next(gen)
            except StopIteration as done:
                return done.value
            jobs["newton"] += 1
            yield

    monkeypatch.setattr(Reg, "_filter", counted_filter)
    monkeypatch.setattr(PhysicsInformedEnsemble, "_take", counted_take)
    monkeypatch.setattr(physics, "combine", counted_combine)
    monkeypatch.setattr(tracking, "combine", counted_combine)
    monkeypatch.setattr(live, "project_steps", counted_steps)
    per_sample, estimates = [], []
    for x, f in zip(X, F, strict=True):
        before = dict(jobs)
        model.observe_one(x, f)
        est = model.predict_one(x, f)
        per_sample.append({k: jobs[k] - before[k] for k in jobs})
        estimates.append(est)
    monkeypatch.undo()
    return per_sample, made, estimates


def test_a_live_model_spreads_its_heavy_work_one_job_per_sample(monkeypatch):
    """With ``project_budget`` (a live link) each sample does at most one heavy job: form
    an equation, test and add the last one, refresh the posterior, or ``project_budget``
    Newton steps of a projection (the first estimate after a start or a detected change is
    made at once). Every estimate shows one posterior the model made, with its own std and
    its consistent phi (the same arithmetic as at once). The at-once model does several in
    one sample (the test can fail)."""
    rng = np.random.default_rng(8)
    junk = DATA.X[rng.integers(0, DATA.n, 1500)] + rng.normal(0.0, 1.0, (1500, 21))
    flanges = DATA.F[rng.integers(0, DATA.n, 1500)]
    heavy = {}
    for budget in (0, 1):
        model = _trained(dynamics=NOMINAL_DYNAMICS, rate_hz=1000.0, update_every=10,
                         point_frames=1)
        model.project_budget = budget
        per_sample, made, estimates = _spread_run(model, junk, flanges, monkeypatch)
        jobs = np.array([[p["formed"], p["tested"], p["refreshed"], min(p["newton"], 1)]
                         for p in per_sample])
        fresh = np.array([bool(e.extra.get("change")) for e in estimates])
        heavy[budget] = jobs[1:][~fresh[1:]].sum(axis=1)  # the first sample and those of
        # a detected change start afresh, at once, by design
        if budget:
            assert fresh.sum() >= 1  # the junk is a change now and then
        if budget:
            assert max(p["newton"] for p in per_sample) <= budget
            assert jobs[:, 3].sum() > 0 and jobs[:, 2].sum() > 10  # it did project, refresh
            by_std = {post.std.tobytes(): post for post in made}
            for est in estimates[1:]:
                post = by_std[est.std.tobytes()]  # KeyError: a posterior never made
                assert np.array_equal(est.phi, project(post.mean, post.precision,
                                                       eps=post.eps))
    assert heavy[1].max() == 1 and heavy[0].max() >= 2


def test_a_live_model_estimates_what_the_at_once_model_does(switch_rollouts):
    """On the new task path with a payload switch at 3 s, fed block points, the spread
    model (physics only) detects the change at the same point as the at-once model, and
    from 0.5 s after the start and after the change its mass is the at-once model's within
    4 g (it shows the same posteriors up to 10 points, 0.1 s, late: a long projection is
    spread over them)."""
    _, switched = switch_rollouts
    runs, changes = {}, {}
    for budget in (0, 4):
        model = PhysicsInformedEnsemble(dynamics=NOMINAL_DYNAMICS, project_budget=budget)
        phis, changes[budget] = [], []
        for k, x in enumerate(_points(switched)):
            model.observe_one(x, None)
            est = model.predict_one(x, None)
            phis.append(est.phi)
            if est.extra.get("change"):
                changes[budget].append(k)
        runs[budget] = np.array(phis)
    assert len(changes[0]) == len(changes[4]) == 1
    assert changes[4] == changes[0]  # at block points only the projection is spread
    settled = np.r_[50:300, changes[4][0] + 50:len(runs[4])]
    gap = np.abs(runs[4][settled, 0] - runs[0][settled, 0])
    assert 0.0 < gap.max() < 4e-3, gap.max()
    budgeted = PhysicsInformedEnsemble(dynamics=NOMINAL_DYNAMICS, project_budget=3)
    assert budgeted.params()["project_budget"] == 3
    with pytest.raises(InvalidInputError, match="project_budget"):
        PhysicsInformedEnsemble(dynamics=NOMINAL_DYNAMICS, project_budget=-1)
