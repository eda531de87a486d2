"""The paper's family of training payloads, built from the geometry of its container.

The paper's payload is a container of 0.790 kg with four slots; each slot takes up to three
steel weights of 0.275 kg. Which slot a weight sits in moves the CoM in x/y, which seat
(height) it sits in moves the CoM in z. Payloads range from the empty container up to five
weights (2.165 kg).

Geometry (all in the flange frame, z along the flange axis away from the robot):

- the container is a uniform solid cuboid of ``BOX_SIZE`` with its centre at ``BOX_CENTRE``;
- the slots are vertical tubes at ``SLOT_XY``; each has three seats, seat ``k`` holding a
  weight whose centre is at ``z = SEAT_BASE_Z + WEIGHT_HEIGHT * (k + 0.5)``;
- a weight is a solid steel cylinder (axis along z) of ``WEIGHT_RADIUS`` and
  ``WEIGHT_HEIGHT``.

A *configuration* is a set of occupied seats ``(slot, seat)``; its payload is the rigid sum of
the container and the weights (:func:`configuration_payload`). Names encode the
configuration: ``"box"`` is the empty container, ``"box+S0k0+S2k1"`` has one weight in slot 0
seat 0 and one in slot 2 seat 1.

**Which 77.** The paper trains on exactly 77 unique payloads of this family but does not list
them. We choose them by a space-filling design: every configuration with 0 to 5 weights is
enumerated (1586, in the order weight count, then :func:`itertools.combinations` over the
seats in ``SEATS`` order), de-duplicated by ``phi`` (:func:`candidate_payloads`), and a greedy
maximin (farthest-point) design picks 77 of them in standardized ``phi`` space (each of the ten
components divided by its standard deviation over the candidates; components with zero spread
are left out). It starts from the empty container and adds, at each step, the candidate whose
smallest distance to those already chosen is largest, ties (distances equal to 1e-9) going to
the earlier candidate.
The result is deterministic and covers the family evenly (:func:`training_payloads`).

**Test payloads** are configurations *not* among the 77: for 2, 3 and 4 weights, the
unselected candidate with that many weights that lies closest (standardized ``phi``) to the
centroid of the training payloads with that many weights, ties to the earlier candidate
(:func:`test_payloads`). Their files are in ``sim/payloads/`` (``test-2w.toml``,
``test-3w.toml``, ``test-4w.toml``; regenerate with ``python -m sim.family``); ``test-3w`` is
the default.
"""

from __future__ import annotations

import functools
import itertools
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np

from iem.errors import PayloadError
from sim.payload import Payload, payload_to_toml

# -- geometry ------------------------------------------------------------------------------
CONTAINER_MASS = 0.790
"""Mass of the empty container, in kg."""
BOX_SIZE = (0.14, 0.14, 0.13)
"""Edge lengths of the container cuboid along flange x, y, z, in m."""
BOX_CENTRE = (0.0, 0.0, 0.065)
"""Centre of the container in the flange frame, in m (it sits on the flange)."""

N_SLOTS = 4
N_SEATS = 3
"""Seats (heights) per slot."""
SLOT_XY = ((0.035, 0.035), (-0.035, 0.035), (-0.035, -0.035), (0.035, -0.035))
"""(x, y) of each slot's axis in the flange frame, in m, indexed by slot."""
SEAT_BASE_Z = 0.005
"""Height of the bottom of seat 0 above the flange, in m."""

WEIGHT_MASS = 0.275
"""Mass of one steel weight, in kg (a 7850 kg/m³ cylinder of this size weighs 0.2751 kg)."""
WEIGHT_RADIUS = 0.017
"""Radius of a weight cylinder, in m."""
WEIGHT_HEIGHT = 0.0386
"""Height of a weight cylinder (and pitch of the seats), in m."""

MAX_WEIGHTS = 5
"""Most weights in one payload (2.165 kg in all)."""
N_TRAINING = 77
"""Number of unique training payloads, as in the paper."""
TEST_WEIGHT_COUNTS = (2, 3, 4)
"""Weight counts of the test payloads ``test-2w``, ``test-3w``, ``test-4w``."""
DEFAULT_TEST = "test-3w"
"""Name of the default test payload."""
PAYLOAD_DIR = Path(__file__).parent / "payloads"
"""Folder of the test payload files shipped with the project."""

SEATS: tuple[tuple[int, int], ...] = tuple(
    (slot, seat) for slot in range(N_SLOTS) for seat in range(N_SEATS)
)
"""All 12 seats as ``(slot, seat)``, in enumeration order."""

_PHI_DECIMALS = 12  # phi rounded to 1e-12 when de-duplicating
_TIE_DECIMALS = 9  # standardized distances rounded to 1e-9 so that ties go to enumeration order


def _seat_centre(slot: int, seat: int) -> np.ndarray:
    """Centre of a weight in ``(slot, seat)``, flange frame, in m."""
    x, y = SLOT_XY[slot]
    return np.array([x, y, SEAT_BASE_Z + WEIGHT_HEIGHT * (seat + 0.5)])


def _box_inertia() -> np.ndarray:
    a, b, c = BOX_SIZE
    m = CONTAINER_MASS
    return np.diag([m * (b * b + c * c), m * (a * a + c * c), m * (a * a + b * b)]) / 12.0


def _weight_inertia() -> np.ndarray:
    m, r, h = WEIGHT_MASS, WEIGHT_RADIUS, WEIGHT_HEIGHT
    side = m * (3 * r * r + h * h) / 12.0
    return np.diag([side, side, m * r * r / 2.0])


def _name(seats: Iterable[tuple[int, int]]) -> str:
    return "".join(["box", *(f"+S{slot}k{seat}" for slot, seat in seats)])


def _validate(seats: Iterable[tuple[int, int]]) -> list[tuple[int, int]]:
    out = []
    for item in seats:
        try:
            slot, seat = (int(v) for v in item)
        except (TypeError, ValueError) as exc:
            raise PayloadError(f"a seat must be a (slot, seat) pair of ints, got {item!r}") from exc
        if (slot, seat) not in SEATS:
            raise PayloadError(f"seat {item!r} does not exist; valid is slot in 0..{N_SLOTS - 1}, "
                               f"seat in 0..{N_SEATS - 1}")
        out.append((slot, seat))
    if len(set(out)) != len(out):
        raise PayloadError(f"a seat holds one weight at most, got {out}")
    return sorted(out)


def configuration_payload(seats: Iterable[tuple[int, int]], name: str | None = None) -> Payload:
    """The payload of the container with a weight in each of ``seats`` (``(slot, seat)`` pairs).

    Mass in kg, CoM in the flange frame in m, inertia about the CoM in flange axes in kg·m²
    (each body's inertia shifted to the common CoM by the parallel-axis theorem). ``name``
    defaults to the configuration's code, e.g. ``"box+S0k0+S2k1"``.
    """
    seats = _validate(seats)
    bodies = [(CONTAINER_MASS, np.asarray(BOX_CENTRE, dtype=float), _box_inertia())]
    bodies += [(WEIGHT_MASS, _seat_centre(*s), _weight_inertia()) for s in seats]
    mass = sum(m for m, _, _ in bodies)
    com = sum(m * c for m, c, _ in bodies) / mass
    inertia = np.zeros((3, 3))
    for m, c, i_c in bodies:
        d = c - com
        inertia += i_c + m * (float(d @ d) * np.eye(3) - np.outer(d, d))
    return Payload(name=name or _name(seats), mass=mass, com=tuple(com), inertia=inertia)


# -- the family ----------------------------------------------------------------------------
@functools.cache
def _candidates() -> tuple[Payload, ...]:
    seen: set[tuple[float, ...]] = set()
    out = []
    for n in range(MAX_WEIGHTS + 1):
        for seats in itertools.combinations(SEATS, n):
            payload = configuration_payload(seats)
            key = tuple(np.round(payload.to_phi(), _PHI_DECIMALS).tolist())
            if key not in seen:
                seen.add(key)
                out.append(payload)
    return tuple(out)


@functools.cache
def _standardized() -> np.ndarray:
    """Candidates' phi, each varying component divided by its std over the candidates."""
    phi = np.array([p.to_phi() for p in _candidates()])
    std = phi.std(axis=0)
    keep = std > 0.0
    return phi[:, keep] / std[keep]


def _maximin(points: np.ndarray, start: int, count: int) -> list[int]:
    """Greedy farthest-point selection of ``count`` rows of ``points``, starting at ``start``."""
    chosen = [start]
    nearest = np.linalg.norm(points - points[start], axis=1)
    for _ in range(count - 1):
        nxt = int(np.argmax(np.round(nearest, _TIE_DECIMALS)))  # ties: enumeration order
        chosen.append(nxt)
        np.minimum(nearest, np.linalg.norm(points - points[nxt], axis=1), out=nearest)
    return chosen


@functools.cache
def _training_indices() -> tuple[int, ...]:
    points = _standardized()
    chosen = _maximin(points, start=0, count=N_TRAINING)  # candidate 0 is the empty container
    if len(set(chosen)) != N_TRAINING:
        raise PayloadError(f"maximin design found only {len(set(chosen))} unique payloads")
    return tuple(chosen)


def _weights_in(payload: Payload) -> int:
    return round((payload.mass - CONTAINER_MASS) / WEIGHT_MASS)


@functools.cache
def _test_payloads() -> tuple[tuple[str, str, Payload], ...]:
    """``(name, configuration, payload)`` of each test payload."""
    cands, points = _candidates(), _standardized()
    training = set(_training_indices())
    counts = np.array([_weights_in(p) for p in cands])
    out = []
    for n in TEST_WEIGHT_COUNTS:
        in_training = sorted(i for i in training if counts[i] == n)
        others = [i for i in range(len(cands)) if counts[i] == n and i not in training]
        # sorted, so the first of equal distances is the earlier candidate
        centroid = points[in_training].mean(axis=0)
        dist = np.linalg.norm(points[others] - centroid, axis=1)
        pick = others[int(np.argmin(np.round(dist, _TIE_DECIMALS)))]
        name = f"test-{n}w"
        out.append((name, cands[pick].name, cands[pick].with_name(name)))
    return tuple(out)


def candidate_payloads() -> list[Payload]:
    """Every unique configuration with 0 to 5 weights, in enumeration order (empty first)."""
    return list(_candidates())


def training_payloads() -> list[Payload]:
    """The 77 training payloads chosen by the maximin design, in the order chosen."""
    cands = _candidates()
    return [cands[i] for i in _training_indices()]


def test_payloads() -> dict[str, Payload]:
    """The test payloads (configurations not among the 77), ``name -> payload``."""
    return {name: payload for name, _, payload in _test_payloads()}


test_payloads.__test__ = False  # not a pytest test, despite its name


def default_test_payload() -> Payload:
    """The default test payload, ``test-3w``."""
    return test_payloads()[DEFAULT_TEST]


def _generic() -> list[Payload]:
    from sim.generic import generic_payloads

    return generic_payloads()


def _cell() -> list[Payload]:
    return training_payloads() + _generic()


FAMILIES: dict[str, Callable[[], list[Payload]]] = {"paper": training_payloads,
                                                    "generic": _generic, "cell": _cell}
"""Named families of training payloads: ``paper`` (the paper's 77 container configurations,
this module), ``generic`` (77 random tools of 0.02 to 3 kg, :mod:`sim.generic`) and ``cell``
(both: 154)."""

DEPLOY_FAMILY = "cell"
"""The family the plug-in trains on unless configured (``[model] family``, ``iem train
--family``). Measured with IEM+phys on the ideal plant, new task path, seed 0 (mass kg /
com kg·m / inertia kg·m², smoothed): the container test payload ``paper`` 0.0006 / 0.0008 /
0.00026, ``generic`` 0.0006 / 0.0025 / 0.0035, ``cell`` 0.0005 / 0.0017 / 0.0016; a 0.4 kg
probe ``paper`` 0.0046 / 0.0015 / 0.00085, ``cell`` 0.0004 / 0.0012 / 0.0007; a 2.8 kg tool
with its CoM 0.1 m off-axis ``paper`` 0.22 / 0.15 / 0.015 with a 2σ coverage of 0 (confidently
wrong), ``generic`` 0.0007 / 0.012 / 0.0048, ``cell`` 0.0009 / 0.012 / 0.0053. The paper's
family is best on its own container and fails on what it does not cover; ``cell`` is never
far from the best and never fails, at twice the training payloads per point."""


def family(name: str) -> list[Payload]:
    """The training payloads of the family called ``name`` (see :data:`FAMILIES`)."""
    try:
        build = FAMILIES[name]
    except KeyError:
        raise PayloadError(f"unknown payload family {name!r}; valid names are "
                           f"{sorted(FAMILIES)}") from None
    return build()


# -- files ---------------------------------------------------------------------------------
def _file_text(name: str, config: str, payload: Payload) -> str:
    """A test payload's file: its configuration as a comment, then the payload TOML."""
    header = (f"# {name}: {config} (container + {_weights_in(payload)} weights)\n"
              "# Generated by sim.family.write_payload_files; do not edit, run "
              "`python -m sim.family`.\n")
    return header + payload_to_toml(payload)


def write_payload_files(folder=PAYLOAD_DIR) -> list[Path]:
    """Write every test payload as ``<folder>/<name>.toml``; return the paths written."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for name, config, payload in _test_payloads():
        path = folder / f"{name}.toml"
        path.write_text(_file_text(name, config, payload), encoding="utf-8")
        paths.append(path)
    return paths


if __name__ == "__main__":
    for written in write_payload_files():
        print(written)
