"""Physical consistency and the projection, against Pinocchio and ``sim.payload.Payload``.

Independent truths: Pinocchio's ``PseudoInertia`` (the 4x4 matrix) and
``LogCholeskyParameters`` (a parametrisation of exactly the consistent bodies), and
``Payload.consistency_violations()`` (mass, positive-definite inertia about the CoM, triangle
inequality, computed from the CoM-frame inertia). The weighted projection is checked against
scipy's SLSQP and against Clarabel (through cvxpy, an interior-point conic solver of its own)
on the same problem.
"""

import numpy as np
import pinocchio as pin
import pytest
from scipy.optimize import minimize

from iem.errors import InvalidInputError
from iem.physics.consistency import (
    EPS,
    from_pseudo_inertia,
    is_consistent,
    min_eigenvalue,
    project,
    project_steps,
    pseudo_inertia,
)
from sim.family import test_payloads, training_payloads
from sim.payload import Payload
from sim.robot import phi_to_pin
from tests.sim.test_robot import phi_from_pin


def _payload_ok(phi) -> bool:
    """The independent check: ``Payload.from_phi`` and its consistency conditions."""
    try:
        return not Payload.from_phi(phi).consistency_violations()
    except Exception:
        return False


def _random_phi(rng, n):
    """Payload-sized parameters, most of them inconsistent (negative mass, bad inertia)."""
    m = rng.uniform(-1.0, 3.0, n)
    h = rng.normal(0.0, 0.2, (n, 3))
    inertia = rng.normal(0.0, 0.01, (n, 6))
    return np.column_stack((m, h, inertia))


def _random_bodies(rng, n):
    """Consistent bodies (four random point masses each), perturbed by noise of random size
    (1e-4 to 1 relative): a mix of consistent and inconsistent parameters near the boundary."""
    out = []
    for _ in range(n):
        m = rng.uniform(0.05, 1.0, 4)
        x = rng.normal(0.0, 0.05, (4, 3)) + rng.normal(0.0, 0.05, 3)
        pts = np.column_stack((x, np.ones(4)))
        phi = from_pseudo_inertia(np.einsum("k,ki,kj->ij", m, pts, pts))
        out.append(phi * (1.0 + 10.0 ** rng.uniform(-4.0, 0.0) * rng.normal(size=10)))
    return np.array(out)


def _random_metric(rng):
    a = rng.normal(size=(10, 10))
    return a @ a.T + np.diag(np.exp(rng.uniform(-5.0, 10.0, 10)))


def test_pseudo_inertia_is_pinocchios():
    rng = np.random.default_rng(0)
    for _ in range(50):
        inertia = pin.Inertia.Random()
        phi = phi_from_pin(inertia.toDynamicParameters())
        J = pin.PseudoInertia.FromDynamicParameters(phi_to_pin(phi)).toMatrix()
        np.testing.assert_allclose(pseudo_inertia(phi), J, atol=1e-12)
        np.testing.assert_allclose(from_pseudo_inertia(J), phi, atol=1e-12)
    batch = _random_phi(rng, 7)
    np.testing.assert_allclose(from_pseudo_inertia(pseudo_inertia(batch)), batch, atol=1e-14)


def test_log_cholesky_bodies_are_consistent_and_left_unchanged():
    """Every body Pinocchio's log-Cholesky parameters describe is consistent, by our test
    and by Payload's, and the projection returns it as it is."""
    rng = np.random.default_rng(1)
    checked = 0
    for _ in range(1000):
        theta = rng.normal(0.0, 0.3, 10)  # off-diagonal Cholesky factors
        theta[:4] = rng.uniform(-4.0, 0.5, 4)  # log-diagonal: reasonable sizes
        params = pin.LogCholeskyParameters(theta).toDynamicParameters()
        phi = phi_from_pin(params)
        if min_eigenvalue(phi) < 1e-6:
            continue  # nearly singular bodies: a rounding error from the boundary
        checked += 1
        assert is_consistent(phi)
        assert _payload_ok(phi)
        assert np.array_equal(project(phi), phi)
        assert np.array_equal(project(phi, _random_metric(rng)), phi)
    assert checked > 700


def test_family_payloads_are_consistent_and_unchanged():
    for payload in [*training_payloads(), *test_payloads().values()]:
        phi = payload.to_phi()
        assert is_consistent(phi) and min_eigenvalue(phi) > EPS
        assert np.array_equal(project(phi), phi)


def test_consistency_agrees_with_payload():
    rng = np.random.default_rng(2)
    phis = np.vstack((_random_phi(rng, 1000), _random_bodies(rng, 2000)))
    ours = np.array([is_consistent(p) for p in phis])
    theirs = np.array([_payload_ok(p) for p in phis])
    assert ours.any() and (~ours).any()
    np.testing.assert_array_equal(ours, theirs)


def test_frobenius_projection_of_thousands_is_consistent():
    rng = np.random.default_rng(3)
    phis = np.vstack((_random_phi(rng, 2500), _random_bodies(rng, 2500)))
    for phi in phis:
        out = project(phi)
        assert is_consistent(out) and min_eigenvalue(out) >= EPS * 0.999
        assert _payload_ok(out)


def test_weighted_projection_of_thousands_is_consistent():
    rng = np.random.default_rng(4)
    for phi in _random_phi(rng, 1000):
        out = project(phi, _random_metric(rng))
        assert is_consistent(out) and _payload_ok(out)


def test_weighted_projection_is_the_nearest_point():
    """Same optimum as SLSQP on ``min (x - phi)^T W (x - phi)`` with ``J(x) >= eps``."""
    rng = np.random.default_rng(5)
    done = 0
    while done < 3:
        phi = _random_phi(rng, 1)[0]
        if is_consistent(phi):
            continue
        W = _random_metric(rng)
        ours = project(phi, W)

        def cost(x, phi=phi, W=W):
            return 0.5 * (x - phi) @ W @ (x - phi)

        ref = minimize(cost, ours, method="SLSQP",
                       constraints=[{"type": "ineq", "fun": lambda x: min_eigenvalue(x) - EPS}],
                       options={"ftol": 1e-15, "maxiter": 1000})
        # SLSQP may end slightly outside the set, so it can only be a little better
        assert cost(ours) <= cost(ref.x) * (1 + 1e-3) + 1e-12
        # and no feasible point along the way from ours toward phi is better
        for s in np.linspace(0.0, 1.0, 11)[1:]:
            x = ours + s * 1e-3 * (phi - ours)
            if min_eigenvalue(x) >= EPS:
                assert cost(x) >= cost(ours) * (1 - 1e-6)
        done += 1


def _clarabel_projection(phi, W, eps=EPS):
    """The reference: ``min 0.5 (x - phi)^T W (x - phi)`` with ``J(x) >= eps E``, solved by
    Clarabel (cvxpy) to a gap of 1e-10 (absolute and relative)."""
    import cvxpy as cp

    x = cp.Variable(10)
    J = sum(x[i] * pseudo_inertia(np.eye(10)[i]) for i in range(10))
    root = np.linalg.cholesky(W)  # W = root root^T
    problem = cp.Problem(cp.Minimize(0.5 * cp.sum_squares(root.T @ (x - phi))),
                         [0.5 * (J + J.T) >> eps * np.eye(4)])
    problem.solve(solver=cp.CLARABEL, tol_gap_abs=1e-10, tol_gap_rel=1e-10, tol_feas=1e-10)
    assert problem.status == "optimal"
    return np.asarray(x.value)


def _clipped_distance(phi, W, eps=EPS):
    """The distance (``0.5 d^T W d``) of the start the projection's tolerance is relative
    to: ``J(phi)``'s eigenvalues raised to ``eps`` plus a millionth of its largest."""
    lam = np.linalg.eigvalsh(pseudo_inertia(phi))
    floor = eps + max(1e-6 * np.abs(lam).max(), 10.0 * eps)
    lam, vec = np.linalg.eigh(pseudo_inertia(phi))
    d = from_pseudo_inertia((vec * np.maximum(lam, floor)) @ vec.T) - phi
    return 0.5 * d @ W @ d


def _newton_steps(phi, W, **kw):
    steps, gen = 0, project_steps(phi, W, **kw)
    while True:
        try:
            next(gen)
            steps += 1
        except StopIteration as done:
            return steps, done.value


@pytest.mark.parametrize("rtol", [1e-3, 1e-6, 1e-9])
def test_weighted_projection_is_within_its_stated_tolerance_of_clarabels(rtol):
    """The weighted projection's promise: a consistent point (``J >= eps E``) whose distance
    exceeds the optimum's by at most ``rtol`` times the smaller of its own and the clipped
    point's distance, checked against Clarabel's optimum; and so (the distance is strongly
    convex in ``W``) within ``sqrt(2 rtol dist0)`` of it in the ``W`` norm. Payload-sized
    bodies just outside the set (the online estimates' case) and far outside it, under badly
    scaled metrics."""
    rng = np.random.default_rng(7)
    cases = [p for p in _random_bodies(rng, 60) if not is_consistent(p, EPS)][:8]
    cases += [p for p in _random_phi(rng, 20) if not is_consistent(p, EPS)][:8]
    assert len(cases) == 16
    for phi in cases:
        W = _random_metric(rng)
        ours = project(phi, W, rtol=rtol)
        ref = _clarabel_projection(phi, W)
        dist0 = _clipped_distance(phi, W)
        assert min_eigenvalue(ours) >= EPS

        def cost(x, phi=phi, W=W):
            return 0.5 * (x - phi) @ W @ (x - phi)

        # Clarabel's own accuracy: its gap tolerance (its point lies a little inside the set
        # or, by 1e-12, outside it, so ours may be the better by that)
        slack = 1e-10 + 1e-9 * cost(ref)
        assert cost(ours) - cost(ref) <= rtol * min(cost(ours), dist0) + slack
        assert cost(ours) >= cost(ref) - slack
        d = ours - ref
        assert np.sqrt(d @ W @ d) <= np.sqrt(2.0 * (rtol * dist0 + slack)) + np.sqrt(2.0 * slack)


def test_weighted_projection_takes_few_newton_steps():
    """The interior-point method starts well inside the set and takes long steps: payload
    bodies just outside it take about five Newton steps, none more than 20 (a log-barrier
    method from the clipped point takes 30-45), and the count is the same run after run."""
    rng = np.random.default_rng(8)
    counts = []
    for phi in _random_bodies(rng, 300):
        if is_consistent(phi, EPS):
            continue
        W = _random_metric(rng)
        steps, out = _newton_steps(phi, W)
        assert np.array_equal(out, project(phi, W))  # the same arithmetic step by step
        assert _newton_steps(phi, W)[0] == steps
        counts.append(steps)
    assert len(counts) > 50
    assert np.mean(counts) <= 10 and max(counts) <= 20, (np.mean(counts), max(counts))


def test_weight_must_be_positive_definite():
    phi = -np.ones(10)
    with pytest.raises(InvalidInputError, match="symmetric positive definite"):
        project(phi, np.diag([1.0] * 9 + [0.0]))
    with pytest.raises(InvalidInputError, match="symmetric positive definite"):
        project(phi, -np.eye(10))


def test_the_metric_moves_the_least_certain_parameters():
    """A CoM too far out for the inertia about the flange can be mended by moving the CoM in
    or by raising the inertia: the metric decides which."""
    phi = test_payloads()["test-3w"].to_phi().copy()
    phi[3] *= 2.0  # m rz doubled: the parallel-axis term exceeds the flange inertia
    assert not is_consistent(phi)
    certain_inertia = np.diag([1e6] * 4 + [1e12] * 6)
    certain_mass = np.diag([1e12] * 4 + [1e6] * 6)
    a = project(phi, certain_inertia)
    b = project(phi, certain_mass)
    assert is_consistent(a) and is_consistent(b)
    np.testing.assert_allclose(a[4:], phi[4:], atol=1e-5)  # inertia kept, m or h moved
    assert np.abs(a[:4] - phi[:4]).max() > 1e-3
    np.testing.assert_allclose(b[:4], phi[:4], atol=1e-5)  # m and h kept, inertia moved
    assert np.abs(b[4:] - phi[4:]).max() > 1e-4


def test_nan_and_bad_shapes():
    assert np.all(np.isnan(project(np.full(10, np.nan))))
    assert not is_consistent(np.full(10, np.nan))
    with pytest.raises(InvalidInputError, match="10 values"):
        pseudo_inertia(np.zeros(9))
    with pytest.raises(InvalidInputError, match="10x10"):
        project(-np.ones(10), np.eye(3))
