""":meth:`iem.ensemble.learner.WeakLearner.fit` against its reference, to the bit.

The fit gathers an epoch's inputs and draws their noise a chunk of whole mini-batches at a
time (the cost of a refit when a bag closes is mostly those draws). The reference here is
the plain algorithm, one mini-batch at a time: gather it, draw its noise, whiten, one SGD
step of the MSE's gradient. Both must give the same learner to the bit (weights, scaling and
the noise generator's state after it), alone and in an ensemble that learns new motion:
its new bags copy the refitted learner of the bag the motion just left, so a refit that
differs in one bit changes every estimate after it.
"""

from __future__ import annotations

import numpy as np
import pytest

from iem.ensemble import IncrementalEnsemble
from iem.ensemble import learner as learner_module
from iem.ensemble.learner import (
    FIT_CHUNK_ROWS,
    SENSOR_NOISE,
    WeakLearner,
    output_range,
    velocity_precision,
)


def reference_fit(X, Y, lo, hi, lr=0.5, input_noise=None, seed=0, epochs=10, batch=77,
                  fit_lr=0.1, pause=None) -> WeakLearner:
    """The fit one mini-batch at a time (its docstring's algorithm, written out plainly)."""
    X, Y = np.asarray(X, dtype=float), np.asarray(Y, dtype=float)
    noise = np.zeros(21) if input_noise is None else np.asarray(input_noise, float)
    center = X.mean(axis=0)
    learner = WeakLearner(lo, hi, center, np.sqrt(X.var(axis=0) + noise ** 2), lr=lr,
                          input_noise=input_noise, seed=seed)
    learner.dq_precision = velocity_precision(X[:, 7:14], noise[7:14])
    inv = learner._inv_scale
    x_all = (X - center) * inv
    lam, vec = np.linalg.eigh(np.cov(x_all.T) + np.diag((noise * inv) ** 2))
    white = vec / np.sqrt(np.maximum(lam, 1e-6 * lam.max()))
    t_all = (Y - learner.lo) / learner._span
    a_u, b, rng = np.zeros((10, 21)), learner.b, learner._rng
    for _ in range(epochs):
        order = rng.permutation(X.shape[0])
        for s in range(0, X.shape[0], batch):
            j = order[s:s + batch]
            x = x_all[j]
            if input_noise is not None:
                x = x + rng.standard_normal(x.shape) * (noise * inv)
            ga, gb, _ = learner_module._gradient(a_u, b, x @ white, t_all[j])
            a_u -= fit_lr * ga
            b -= fit_lr * gb
    learner.a, learner.b = a_u @ white.T, b
    return learner


def state_bytes(learner: WeakLearner) -> bytes:
    """Everything a learner computes with or saves, as bytes (its generator's state too)."""
    arrays = (learner.a, learner.b, learner.center, learner.scale, learner.dq_precision)
    return b"".join(a.tobytes() for a in arrays) + repr(learner._rng.bit_generator.state).encode()


def _bag(n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    X = rng.normal(0.0, 1.0, (n, 21)) @ rng.normal(0.0, 0.5, (21, 21)) + rng.normal(0, 2, 21)
    Y = X[:, :10] @ rng.normal(0, 0.1, (10, 10)) + 1.0
    return X, Y


@pytest.mark.parametrize(("n", "batch"), [
    (4 * FIT_CHUNK_ROWS + 531, 154),   # chunks, and an epoch's last mini-batch short
    (3 * 154, 154),                    # less than a chunk, whole mini-batches
    (50, 154),                         # fewer rows than one mini-batch
    (2 * FIT_CHUNK_ROWS + 7, FIT_CHUNK_ROWS + 5),  # mini-batches larger than a chunk
])
@pytest.mark.parametrize("noise", [SENSOR_NOISE, None])
def test_fit_is_the_reference_to_the_bit(n, batch, noise):
    X, Y = _bag(n)
    lo, hi = output_range(Y)
    kw = {"input_noise": noise, "seed": [3, 1, 3], "epochs": 3, "batch": batch}
    got, want = WeakLearner.fit(X, Y, lo, hi, **kw), reference_fit(X, Y, lo, hi, **kw)
    assert state_bytes(got) == state_bytes(want)
    assert np.abs(want.a).max() > 0  # it did learn


def test_the_reference_tells_a_last_digit_apart():
    """The comparison can fail: a refit on data that differ in one value's 12th significant
    digit is another learner. (One ulp can vanish in the rounding of the sums it enters,
    depending on the machine's kernels: it did on OpenBLAS's Sandybridge kernel.)"""
    X, Y = _bag(600)
    lo, hi = output_range(Y)
    kw = {"input_noise": SENSOR_NOISE, "seed": 1, "epochs": 2, "batch": 60}
    nudged = X.copy()
    nudged[17, 3] *= 1.0 + 1e-12
    assert state_bytes(WeakLearner.fit(nudged, Y, lo, hi, **kw)) != \
        state_bytes(reference_fit(X, Y, lo, hi, **kw))


# -- an ensemble learning new motion ---------------------------------------------------------
K = 60
"""Training payloads: a bag's refit holds up to ``reservoir * K`` rows (several chunks)."""
_RNG = np.random.default_rng(7)
_A = _RNG.normal(0, 1, (7, 10))
_PHI = np.column_stack((_RNG.uniform(0.3, 2.5, K), _RNG.uniform(-0.05, 0.05, (K, 3)),
                        _RNG.uniform(0.001, 0.01, (K, 6))))


def _samples(q, dq):
    tau = (_PHI @ _A.T) * (1 + 0.2 * np.sin(q)) + 0.05 * dq
    return np.column_stack((np.tile(q, (K, 1)), np.tile(dq, (K, 1)), tau)), _PHI


def _motion(seconds: float, rate: float, phase: float):
    """Joint positions and velocities of a smooth motion that sweeps across many bags."""
    t = np.arange(0.0, seconds, 1.0 / rate)[:, None]
    w = np.linspace(0.6, 1.3, 7)
    return np.sin(w * t + phase) * 1.2, np.cos(w * t + phase) * 1.2 * w


def _replay(monkeypatch, fit) -> tuple[list[bytes], int, int]:
    """Estimates (bytes) of a fitted ensemble learning new motion, with ``fit`` as the
    learners' fit; the refits it made and their largest row count."""
    refits = []

    def counted(cls, X, Y, *args, **kw):
        refits.append(len(X))
        return fit(X, Y, *args, **kw)

    monkeypatch.setattr(WeakLearner, "fit", classmethod(counted))
    model = IncrementalEnsemble(delta=0.35, rho=0.15, reservoir=60, fit_epochs=3, seed=4)
    Q, DQ = _motion(3.0, 20.0, 0.0)
    model.fit(Q, Q[:, :3] * 0.3, lambda i: _samples(Q[i], DQ[i]))
    initial = len(refits)
    out = []
    Q, DQ = _motion(6.0, 100.0, 2.0)  # elsewhere: new bags, each refitted when left
    for q, dq in zip(Q, DQ, strict=True):
        X, Y = _samples(q, dq)
        x = np.concatenate((q, dq, X[0, 14:]))
        est = model.learn_predict_raw(x, q[:3] * 0.3, (X, Y))
        out.append(est.phi.tobytes() + np.int64(est.bag).tobytes())
    model.close()
    out.extend(state_bytes(model.learner(b)) for b in range(model.n_bags))
    return out, len(refits) - initial, max(refits[initial:], default=0)


def test_new_motion_gives_the_reference_estimates_to_the_bit(monkeypatch):
    plain = WeakLearner.fit.__func__
    got, refits, rows = _replay(monkeypatch, lambda *a, **kw: plain(WeakLearner, *a, **kw))
    want, ref_refits, _ = _replay(monkeypatch, reference_fit)
    assert refits == ref_refits >= 5 and rows > FIT_CHUNK_ROWS  # refits of more than a chunk
    assert len(got) == len(want)
    assert got == want
