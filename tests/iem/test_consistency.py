"""Physical consistency and the projection, against Pinocchio and ``sim.payload.Payload``.

Independent truths: Pinocchio's ``PseudoInertia`` (the 4x4 matrix) and
``LogCholeskyParameters`` (a parametrisation of exactly the consistent bodies), and
``Payload.consistency_violations()`` (mass, positive-definite inertia about the CoM, triangle
inequality, computed from the CoM-frame inertia). The weighted projection is checked against
scipy's SLSQP on the same problem.
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
