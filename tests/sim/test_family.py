"""The paper's payload family: counts, physics, the hand-checked geometry and the shipped files."""

from __future__ import annotations

import time

import numpy as np
import pytest

from iem.errors import PayloadError
from sim import family as fam
from sim.payload import load_payload

MASS_LEVELS = [0.790 + 0.275 * n for n in range(6)]  # kg: empty container .. five weights


def _phi_matches(phi, others, tol=1e-9):
    return bool(np.any(np.all(np.abs(np.asarray(others) - phi) <= tol, axis=1)))


def test_build_is_fast():
    fam._candidates.cache_clear()
    fam._standardized.cache_clear()
    fam._training_indices.cache_clear()
    fam._test_payloads.cache_clear()
    start = time.perf_counter()
    fam.training_payloads()
    fam.test_payloads()
    assert time.perf_counter() - start < 2.0


def test_candidates_cover_all_configurations():
    cands = fam.candidate_payloads()
    assert cands[0].name == "box"
    assert len(cands) <= 1586  # 1 + 12 + 66 + 220 + 495 + 792 configurations before dedup
    phi = np.round([p.to_phi() for p in cands], 12)
    assert len({tuple(row) for row in phi}) == len(cands)


def test_exactly_77_unique_consistent_training_payloads():
    training = fam.training_payloads()
    assert len(training) == fam.N_TRAINING == 77
    phi = np.round([p.to_phi() for p in training], 12)
    assert len({tuple(row) for row in phi}) == 77
    assert len({p.name for p in training}) == 77
    for p in training:
        assert p.check() is p
    assert training[0].name == "box"


def test_training_set_is_deterministic_and_a_fresh_list():
    a, b = fam.training_payloads(), fam.training_payloads()
    assert a == b and a is not b
    a.clear()
    assert len(fam.training_payloads()) == 77


def test_mass_range_and_all_six_levels():
    masses = np.array([p.mass for p in fam.training_payloads()])
    assert masses.min() == pytest.approx(0.790)
    assert masses.max() == pytest.approx(2.165)
    for level in MASS_LEVELS:
        assert np.any(np.isclose(masses, level)), level


def test_test_payloads_are_outside_training_and_consistent():
    tests = fam.test_payloads()
    assert set(tests) >= {"test-2w", "test-3w", "test-4w"}
    training_phi = np.array([p.to_phi() for p in fam.training_payloads()])
    for name, p in tests.items():
        assert p.name == name
        assert p.check() is p
        assert not _phi_matches(p.to_phi(), training_phi)
    for n in (2, 3, 4):
        assert tests[f"test-{n}w"].mass == pytest.approx(MASS_LEVELS[n])
    assert fam.default_test_payload() == tests["test-3w"]


def test_one_weight_by_hand():
    """Container plus one weight in slot 0, seat 0, worked out independently."""
    # container: solid cuboid 0.14 x 0.14 x 0.13 m, 0.790 kg, centre (0, 0, 0.065)
    mb, a, b, c = 0.790, 0.14, 0.14, 0.13
    box_c = np.array([0.0, 0.0, 0.065])
    box_i = np.diag([mb * (b**2 + c**2) / 12, mb * (a**2 + c**2) / 12, mb * (a**2 + b**2) / 12])
    # weight: cylinder r 0.017 m, h 0.0386 m, 0.275 kg, centre (0.035, 0.035, 0.005 + 0.0193)
    mw, r, h = 0.275, 0.017, 0.0386
    w_c = np.array([0.035, 0.035, 0.005 + 0.0193])
    w_i = np.diag([mw * (3 * r**2 + h**2) / 12, mw * (3 * r**2 + h**2) / 12, mw * r**2 / 2])

    m = mb + mw
    com = (mb * box_c + mw * w_c) / m
    assert m == pytest.approx(1.065)
    assert com == pytest.approx([0.275 * 0.035 / 1.065, 0.275 * 0.035 / 1.065,
                                 (0.790 * 0.065 + 0.275 * 0.0243) / 1.065])

    def shift(mass, d):  # parallel-axis term, written out element by element
        x, y, z = d
        return mass * np.array([[y * y + z * z, -x * y, -x * z],
                                [-x * y, x * x + z * z, -y * z],
                                [-x * z, -y * z, x * x + y * y]])

    inertia = box_i + shift(mb, box_c - com) + w_i + shift(mw, w_c - com)

    p = fam.configuration_payload([(0, 0)])
    assert p.name == "box+S0k0"
    assert p.mass == pytest.approx(m, abs=1e-15)
    np.testing.assert_allclose(p.com, com, rtol=0, atol=1e-15)
    np.testing.assert_allclose(p.inertia_matrix, inertia, rtol=1e-12, atol=1e-15)
    assert p.inertia[1] < 0  # Ixy: the weight sits at +x, +y relative to the CoM


def test_empty_container_is_the_box():
    p = fam.configuration_payload([])
    assert p.name == "box"
    assert p.mass == 0.790
    assert p.com == (0.0, 0.0, 0.065)
    np.testing.assert_allclose(p.inertia, [0.790 * (0.14**2 + 0.13**2) / 12, 0, 0,
                                           0.790 * (0.14**2 + 0.13**2) / 12, 0,
                                           0.790 * (0.14**2 + 0.14**2) / 12])


def test_slot_moves_rx_ry_and_seat_moves_rz():
    signs = {0: (1, 1), 1: (-1, 1), 2: (-1, -1), 3: (1, -1)}
    ref = fam.configuration_payload([(0, 1)])
    for slot, (sx, sy) in signs.items():
        p = fam.configuration_payload([(slot, 1)])
        assert np.sign(p.com[0]) == sx and np.sign(p.com[1]) == sy
        assert p.com[2] == pytest.approx(ref.com[2])  # same seat, same height
    zs = [fam.configuration_payload([(2, k)]).com for k in range(3)]
    assert zs[0][2] < zs[1][2] < zs[2][2]
    for z in zs:  # same slot, same rx/ry
        assert z[:2] == pytest.approx(zs[0][:2])


def test_configuration_names_and_order():
    p = fam.configuration_payload([(2, 1), (0, 0)])
    assert p.name == "box+S0k0+S2k1"
    assert fam.configuration_payload([(0, 0)], name="x").name == "x"


@pytest.mark.parametrize("seats", [[(4, 0)], [(0, 3)], [(0, 0), (0, 0)], [("a", 0)], [1]])
def test_bad_seats_are_rejected(seats):
    with pytest.raises(PayloadError, match="seat"):
        fam.configuration_payload(seats)


def test_family_table():
    assert fam.family("paper") == fam.training_payloads()
    with pytest.raises(PayloadError, match="paper"):
        fam.family("nope")


def test_repo_payload_files_match_the_generator(tmp_path):
    written = fam.write_payload_files(tmp_path)
    assert sorted(p.name for p in written) == ["test-2w.toml", "test-3w.toml", "test-4w.toml"]
    for path in written:
        shipped = fam.PAYLOAD_DIR / path.name
        assert shipped.exists(), f"{shipped} missing; run `python -m sim.family`"
        new_lines = path.read_text(encoding="utf-8").splitlines()
        old_lines = shipped.read_text(encoding="utf-8").splitlines()
        comments = [line for line in new_lines if line.startswith("#")]
        assert comments == [line for line in old_lines if line.startswith("#")]
        new, old = load_payload(path), load_payload(shipped)
        assert new.name == old.name == path.stem
        # values compared to 1e-12 rather than as text, so last-bit float noise cannot fail it
        np.testing.assert_allclose(old.to_phi(), new.to_phi(), rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(old.to_phi(), fam.test_payloads()[path.stem].to_phi(),
                                   rtol=1e-12, atol=1e-15)
    assert sorted(p.name for p in fam.PAYLOAD_DIR.glob("test-*.toml")) == sorted(
        p.name for p in written)
