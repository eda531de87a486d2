"""Starting IEM+phys from a known payload (issue 16: the service starts from what
``iem identify`` found): the file is the first estimate and the prior, unverified until the
live data have tested it, and a wrong file gives way to the data."""

from __future__ import annotations

import numpy as np
import pytest

from iem.errors import InvalidInputError
from iem.persistence import dumps, loads
from iem.physics import DETECT_AFTER, PhysicsInformedEnsemble

from .test_physics import FAKE, PHI, _hand_made


def _run(model, X):
    out = []
    for x in X:
        model.observe_one(x, None)
        out.append(model.predict_one(x, None))
    return out


def test_the_file_is_the_first_estimate_and_stays_unverified_until_tested():
    model = PhysicsInformedEnsemble(dynamics=FAKE, update_every=10)
    std = np.full(10, 1e-3)
    model.start_from(PHI, std)
    first = model.predict_one(_hand_made(1)[0], None)
    np.testing.assert_allclose(first.phi, PHI, atol=1e-9)
    np.testing.assert_allclose(first.std, np.sqrt(std ** 2 + 0.0), rtol=0.05)
    assert first.unverified
    est = _run(model, _hand_made(3000))
    flags = [e.unverified for e in est]
    first_verified = flags.index(False)
    assert all(flags[:first_verified]) and not any(flags[first_verified:])
    assert model._m >= DETECT_AFTER and model.changes == 0
    np.testing.assert_allclose(est[-1].phi, PHI, atol=5e-3)


def test_a_wrong_file_gives_way_to_the_data():
    wrong = PHI.copy()
    wrong[0] += 0.3  # 300 g heavier than what is mounted
    model = PhysicsInformedEnsemble(dynamics=FAKE, update_every=10)
    model.start_from(wrong, np.full(10, 1e-3))
    est = _run(model, _hand_made(4000))
    assert abs(est[-1].phi[0] - PHI[0]) < 0.01  # the data, not the file
    assert model.changes >= 1 or model.prior_inflation > 10.0


def test_start_from_survives_a_checkpoint_and_is_checked():
    model = PhysicsInformedEnsemble(dynamics=FAKE, update_every=10)
    model.start_from(PHI, np.full(10, 2e-3))
    back = loads(dumps(model))
    np.testing.assert_allclose(back.predict_one(_hand_made(1)[0], None).phi, PHI, atol=1e-9)
    with pytest.raises(InvalidInputError, match="std > 0"):
        model.start_from(PHI, np.zeros(10))
