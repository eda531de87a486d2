"""The payload value type: phi, set_load arguments, physical consistency, TOML files."""

import numpy as np
import pytest

from iem.errors import IemError, PayloadError
from sim.payload import Payload, load_payload, payload_to_toml, save_payload

BOX = Payload("box", 1.2, (0.01, -0.02, 0.05), (0.004, 1e-4, -2e-4, 0.005, 3e-4, 0.003))


def test_phi_uses_parallel_axis_theorem():
    m, c = BOX.mass, np.array(BOX.com)
    phi = BOX.to_phi()
    assert phi[0] == m
    np.testing.assert_allclose(phi[1:4], m * c)
    # Ixx about the flange origin = Ixx_c + m (cy² + cz²); Ixy = Ixy_c - m cx cy
    assert phi[4] == pytest.approx(0.004 + m * (c[1] ** 2 + c[2] ** 2))
    assert phi[5] == pytest.approx(1e-4 - m * c[0] * c[1])
    assert phi[6] == pytest.approx(-2e-4 - m * c[0] * c[2])
    assert phi[7] == pytest.approx(0.005 + m * (c[0] ** 2 + c[2] ** 2))
    assert phi[8] == pytest.approx(3e-4 - m * c[1] * c[2])
    assert phi[9] == pytest.approx(0.003 + m * (c[0] ** 2 + c[1] ** 2))


def test_phi_round_trip():
    back = Payload.from_phi(BOX.to_phi())
    assert back.mass == pytest.approx(BOX.mass)
    np.testing.assert_allclose(back.com, BOX.com, atol=1e-15)
    np.testing.assert_allclose(back.inertia, BOX.inertia, atol=1e-15)


def test_set_load_args_column_major():
    mass, com, inertia = BOX.set_load_args()
    assert mass == BOX.mass and com == list(BOX.com)
    assert len(inertia) == 9
    # column-major: element (row 0, col 1) is at index 3, (row 0, col 2) at index 6
    assert inertia[3] == BOX.inertia[1] and inertia[6] == BOX.inertia[2]
    assert inertia[7] == BOX.inertia[4]
    back = Payload.from_set_load(mass, com, inertia)
    assert back.inertia == pytest.approx(BOX.inertia)


def test_asymmetric_column_major_order():
    """A non-symmetric 3x3 makes the order visible: Fortran order reads down columns."""
    m = np.arange(9.0).reshape(3, 3)
    assert list(m.flatten(order="F")) == [0, 3, 6, 1, 4, 7, 2, 5, 8]


@pytest.mark.parametrize(
    ("payload", "words"),
    [
        (Payload("m0", 0.0, (0, 0, 0), (1e-3, 0, 0, 1e-3, 0, 1e-3)), "mass must be > 0"),
        (Payload("neg", 1.0, (0, 0, 0), (-1e-3, 0, 0, 1e-3, 0, 1e-3)), "positive definite"),
        (Payload("tri", 1.0, (0, 0, 0), (1e-3, 0, 0, 1e-3, 0, 5e-3)), "triangle inequality"),
        (Payload("nan", float("nan"), (0, 0, 0), (1e-3, 0, 0, 1e-3, 0, 1e-3)), "finite"),
    ],
)
def test_consistency_check_names_the_failed_condition(payload, words):
    assert not payload.is_consistent()
    with pytest.raises(PayloadError, match=words):
        payload.check()


def test_consistent_payload_passes_and_thin_rod_is_the_limit():
    assert BOX.check() is BOX
    # a thin rod along z: I1 = I2 = I, I3 = 0 -> not positive definite
    rod = Payload("rod", 1.0, (0, 0, 0), (1e-3, 0, 0, 1e-3, 0, 0.0))
    assert "positive definite" in rod.consistency_violations()[0]
    # a flat plate: I3 = I1 + I2 exactly is allowed
    plate = Payload("plate", 1.0, (0, 0, 0), (1e-3, 0, 0, 2e-3, 0, 3e-3))
    assert plate.is_consistent()


def test_errors_share_the_project_root():
    assert issubclass(PayloadError, IemError)


def test_toml_round_trip(tmp_path):
    f = tmp_path / "p.toml"
    save_payload(BOX, f)
    back = load_payload(f)
    assert back == BOX


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ('mass = 1.0\ncom = [0, 0, 0]\ninertia = [1e-3, 0, 0, 1e-3, 0, 1e-3]', "missing key"),
        ('name = "x"\nmass = -1.0\ncom = [0, 0, 0]\ninertia = [1e-3, 0, 0, 1e-3, 0, 1e-3]',
         "'mass'.*valid is"),
        ('name = "x"\nmass = 20.0\ncom = [0, 0, 0]\ninertia = [1e-3, 0, 0, 1e-3, 0, 1e-3]',
         "'mass'.*valid is"),
        ('name = "x"\nmass = "heavy"\ncom = [0, 0, 0]\ninertia = [1e-3, 0, 0, 1e-3, 0, 1e-3]',
         "'mass' must be a number"),
        ('name = "x"\nmass = 1.0\ncom = [0, 0]\ninertia = [1e-3, 0, 0, 1e-3, 0, 1e-3]',
         "'com' must be a list of 3"),
        ('name = "x"\nmass = 1.0\ncom = [0, 0, 5]\ninertia = [1e-3, 0, 0, 1e-3, 0, 1e-3]',
         r"'com'\[2\].*valid is"),
        ('name = "x"\nmass = 1.0\ncom = [0, 0, 0]\ninertia = [1e-3, 0, 0, 1e-3, 0]',
         "'inertia' must be a list of 6"),
        ('name = "x"\nmass = 1.0\ncom = [0, 0, 0]\ninertia = [1e-3, 0, 0, 1e-3, 0, 9e-3]',
         "'inertia' is not physically consistent.*triangle"),
        ('name = "x"\nmass = 1.0\ncom = [0, 0, 0]\ninertia = [1e-3, 0, 0, 1e-3, 0, 1e-3]\n'
         'colour = "red"', "unknown key"),
        ('name = "x"\nmass = 1.0\ncom = [0, 0, 0', "not valid TOML"),
        # a misspelt key: named, with what it was meant to be (not "missing key 'mass'")
        ('name = "x"\nmas = 1.0\ncom = [0, 0, 0]\ninertia = [1e-3, 0, 0, 1e-3, 0, 1e-3]',
         r"unknown key\(s\) 'mas' \(did you mean 'mass'\?\); valid keys are"),
        ('name = "x"\nmass = 1.0\ncom = [0, 0, 0]\ninertia = [1e-3, 0, 0, 1e-3, 0, 1e-3]\n'
         'x = ' + '[' * 40 + ']' * 40, "nested more than 32 deep on line 5"),
    ],
)
def test_bad_files_name_the_key_and_valid_range(tmp_path, text, words):
    f = tmp_path / "bad.toml"
    f.write_text(text)
    with pytest.raises(PayloadError, match=words) as info:
        load_payload(f)
    assert str(f) in str(info.value)


def test_a_fifo_is_refused_not_waited_on(tmp_path):
    """A FIFO named as a payload file (an end effector, an initial payload) would block the
    read until a writer came: it is refused at once, as every file a user hands over is."""
    import os

    from tests.watchdog import within

    fifo = tmp_path / "tool.toml"
    os.mkfifo(fifo)
    with within(10), pytest.raises(PayloadError, match="it is a FIFO \\(named pipe\\); valid "
                                                       "is a regular file"):
        load_payload(fifo)


def test_missing_file_is_a_clear_error(tmp_path):
    with pytest.raises(PayloadError, match="cannot read the payload file: it does not exist"):
        load_payload(tmp_path / "none.toml")


def test_toml_text_mentions_units():
    text = payload_to_toml(BOX)
    assert "kg" in text and "flange" in text
