"""The ``generic`` family of tools (sim.generic): physically consistent by Pinocchio's own
test, within the stated ranges, seeded, and usable for training."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from sim.family import FAMILIES, family
from sim.generic import DENSITY, MAX_COM, MAX_MASS, MIN_MASS, generic_payloads


def test_every_member_is_a_rigid_body_by_pinocchio():
    for p in family("generic"):
        inertia = pin.Inertia(p.mass, np.array(p.com), p.inertia_matrix)
        pseudo = pin.PseudoInertia.FromInertia(inertia).toMatrix()
        assert np.linalg.eigvalsh(pseudo).min() > 0, p.name
        np.testing.assert_allclose(inertia.toDynamicParameters()[0], p.mass)


def test_the_family_spans_what_a_cell_mounts():
    tools = generic_payloads()
    mass = np.array([p.mass for p in tools])
    com = np.array([np.linalg.norm(p.com) for p in tools])
    assert MIN_MASS <= mass.min() < 0.3 and 2.5 < mass.max() <= MAX_MASS
    assert com.max() <= MAX_COM + 1e-12 and com.max() > 0.1
    off_axis = np.array([np.hypot(p.com[0], p.com[1]) for p in tools])
    assert (off_axis > 0.05).sum() >= 10  # tools that carry mass sideways
    # each inertia is that of a real object of its mass: the principal moments of a solid
    # of density at most DENSITY[1] cannot be smaller than a steel cube's of that mass
    for p in tools:
        cube = p.mass / 6.0 * (p.mass / DENSITY[1]) ** (2.0 / 3.0)
        assert np.linalg.eigvalsh(p.inertia_matrix).min() > 0.02 * cube, p.name


def test_seeded_and_registered():
    assert "generic" in FAMILIES
    a, b = generic_payloads(count=10, seed=3), generic_payloads(count=10, seed=3)
    assert [p.to_phi().tolist() for p in a] == [p.to_phi().tolist() for p in b]
    assert generic_payloads(count=10, seed=4)[0] != a[0]


def test_a_model_trains_on_it():
    from deploy.model.training import train_initial_model

    model = train_initial_model("IEM", family="generic", log=lambda *a: None, fit_epochs=2,
                                fit_stride=50)
    assert model.n_bags >= 1


def test_a_model_file_records_its_family_and_the_service_refuses_another(tmp_path):
    import pytest

    from deploy.config import ConfigError
    from deploy.model.training import check_model_family, train_initial_model
    from iem.persistence import dumps, load_model, loads, save_model

    model = train_initial_model("IEM", family="generic", log=lambda *a: None, fit_epochs=1,
                                fit_stride=100)
    path = tmp_path / "m.msgpack"
    save_model(model, path)
    back = load_model(path)
    assert back.trained_family == "generic"
    check_model_family(back, "generic")
    with pytest.raises(ConfigError, match=r"family 'generic'.*family = 'generic'"):
        check_model_family(back, "paper")
    data = bytearray(dumps(model))
    data[data.index(b"generic")] ^= 1  # the record is covered by the file's CRC
    with pytest.raises(Exception, match="corrupt"):
        loads(bytes(data))
    paper = train_initial_model("IEM", family="paper", log=lambda *a: None, fit_epochs=1,
                                fit_stride=100)
    check_model_family(loads(dumps(paper)), "paper")  # the default: no record at all
    assert b"family" not in dumps(paper)
