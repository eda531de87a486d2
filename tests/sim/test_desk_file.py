"""Franka Desk's end-effector file (``endeffector-config.json``): read, checked field by
field, written, and taken as an end effector."""

from __future__ import annotations

import json

import numpy as np
import pytest

from iem.errors import PayloadError
from sim.desk_file import (
    FRANKA_HAND_TRANSFORMATION,
    IDENTITY,
    desk_document,
    desk_from_dict,
    read_desk_file,
)
from sim.end_effector import end_effector
from sim.family import default_test_payload
from sim.payload import save_payload


@pytest.fixture
def doc():
    return desk_document(default_test_payload(), id="gripper-camera", name="gripper + camera")


def test_a_written_file_reads_back_as_the_same_body(doc, tmp_path):
    p = default_test_payload()
    path = tmp_path / "endeffector-config.json"
    path.write_text(json.dumps(doc))
    back = read_desk_file(path)
    assert (back.id, back.name, back.transformation) == ("gripper-camera", "gripper + camera",
                                                         IDENTITY)
    assert back.payload.mass == p.mass
    np.testing.assert_allclose(back.payload.com, p.com, rtol=0, atol=1e-15)
    np.testing.assert_allclose(back.payload.inertia, p.inertia, rtol=0, atol=1e-15)
    assert len(doc["transformation"]) == 16 and len(doc["inertia"]) == 9


def test_as_an_end_effector_it_is_the_body_its_toml_twin_is(doc, tmp_path):
    desk, toml = tmp_path / "tool.json", tmp_path / "tool.toml"
    desk.write_text(json.dumps(doc))
    save_payload(default_test_payload(), toml)
    a, b = end_effector(str(desk)), end_effector(str(toml))
    assert a.mass == b.mass
    np.testing.assert_allclose(a.inertia.toDynamicParameters(),
                               b.inertia.toDynamicParameters(), rtol=0, atol=1e-15)
    massless = dict(doc, mass=0.0, centerOfMass=[0.0] * 3, inertia=[0.0] * 9)
    desk.write_text(json.dumps(massless))
    assert end_effector(str(desk)).inertia is None


def test_the_franka_hands_frame_is_its_nominal_tcp():
    m = np.reshape(FRANKA_HAND_TRANSFORMATION, (4, 4), order="F")
    np.testing.assert_allclose(m[:3, 3], [0.0, 0.0, 0.1034])
    np.testing.assert_allclose(m[:2, :2], [[np.cos(-np.pi / 4), -np.sin(-np.pi / 4)],
                                           [np.sin(-np.pi / 4), np.cos(-np.pi / 4)]])


@pytest.mark.parametrize(("change", "field", "words"), [
    ({"mass": None}, "'mass'", "missing field"),
    ({"mass": "1.2"}, "'mass'", "finite number"),
    ({"mass": -1.0}, "'mass'", "out of range"),
    ({"centerOfMass": [0.0, 0.1]}, "'centerOfMass'", "3 numbers"),
    ({"transformation": [1.0] * 12}, "'transformation'", "16 numbers"),
    ({"transformation": [1, 0, 0, 0.1, 0, 1, 0, 0, 0, 0, 1, 0.2, 0, 0, 0, 1]},
     "'transformation'", "row-major"),
    ({"transformation": [2, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]},
     "'transformation'", "no rotation"),
    ({"inertia": [1e-3, 1e-4, 0, 0, 1e-3, 0, 0, 0, 1e-3]}, "'inertia'", "not symmetric"),
    ({"inertia": [1e-3, 0, 0, 0, 1e-3, 0, 0, 0, 3e-3]}, "'inertia'", "not physical"),
    ({"id": "ee-gripper"}, "'id'", "not beginning with 'ee-'"),
    ({"name": 7}, "'name'", "a string"),
])
def test_a_wrong_field_is_named(doc, change, field, words):
    bad = dict(doc)
    for key, value in change.items():
        if value is None:
            del bad[key]
        else:
            bad[key] = value
    with pytest.raises(PayloadError, match=words) as err:
        desk_from_dict(bad)
    assert field in str(err.value)


def test_a_file_that_is_not_json_is_refused(tmp_path):
    path = tmp_path / "endeffector-config.json"
    path.write_text("{mass: 1")
    with pytest.raises(PayloadError, match="not valid JSON"):
        read_desk_file(path)
    with pytest.raises(PayloadError, match="cannot read"):
        read_desk_file(tmp_path / "missing.json")
