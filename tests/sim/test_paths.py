"""Joint paths: shapes, analytic consistency, limits, the paper's bag counts, joining, CSV files."""

from __future__ import annotations

import io
import math
import os
import re

import numpy as np
import pytest

from iem.errors import PathError
from sim.paths import (
    EXCITATION_PERIOD,
    Q0,
    Q_END,
    Q_START,
    RATE_HZ,
    Path,
    excitation_path,
    linear_path,
    load_path_csv,
    new_task_path,
    rest_path,
    save_path_csv,
)
from sim.robot import arm_model
from tests.watchdog import within

H = 1.0 / RATE_HZ
DELTA = math.radians(30.0)  # the paper's joint-space threshold, rad
RHO = 0.2  # the paper's flange-position threshold, m


# -- a reference bag router (paper, Algorithm 1 with the thresholds of section 4.1) ----------
class BagRouter:
    """Each point joins the nearest bag (joint space) whose running mean is within ``DELTA``
    in joint space and ``RHO`` at the flange; otherwise it starts a new bag."""

    def __init__(self) -> None:
        self.counts: list[int] = []
        self.q_means: list[np.ndarray] = []
        self.x_means: list[np.ndarray] = []

    def __len__(self) -> int:
        return len(self.counts)

    def route(self, Q: np.ndarray) -> BagRouter:
        X = arm_model().flange_positions(Q)
        for q, x in zip(Q, X, strict=True):
            best, best_d = -1, math.inf
            for s, (qm, xm) in enumerate(zip(self.q_means, self.x_means, strict=True)):
                d = math.dist(q, qm)
                if d < DELTA and math.dist(x, xm) < RHO and d < best_d:
                    best, best_d = s, d
            if best < 0:
                self.counts.append(1)
                self.q_means.append(q.copy())
                self.x_means.append(x.copy())
            else:
                self.counts[best] += 1
                n = self.counts[best]
                self.q_means[best] += (q - self.q_means[best]) / n
                self.x_means[best] += (x - self.x_means[best]) / n
        return self


# -- fixtures --------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def excitation() -> Path:
    return excitation_path()


@pytest.fixture(scope="module")
def new_task() -> Path:
    return new_task_path()


def _at_rest(p: Path, k: int, tol: float = 1e-9) -> bool:
    return bool(np.all(np.abs(p.dq[k]) <= tol) and np.all(np.abs(p.ddq[k]) <= tol))


def _assert_consistent(p: Path, rel: float = 1e-4) -> None:
    """Central differences of q match dq, and of dq match ddq, at 1 ms steps."""
    dq_fd = (p.q[2:] - p.q[:-2]) / (2 * H)
    ddq_fd = (p.dq[2:] - p.dq[:-2]) / (2 * H)
    np.testing.assert_allclose(dq_fd, p.dq[1:-1], rtol=0,
                               atol=rel * max(np.abs(p.dq).max(), 1e-3))
    np.testing.assert_allclose(ddq_fd, p.ddq[1:-1], rtol=0,
                               atol=rel * max(np.abs(p.ddq).max(), 1e-3))


# -- shapes and sampling -----------------------------------------------------------------------
@pytest.mark.parametrize("make, duration", [
    (lambda: excitation_path(), 20.0),
    (lambda: new_task_path(), 6.0),
    (lambda: linear_path(Q0, Q_END, 2.5, "lin"), 2.5),
    (lambda: rest_path(Q0, 0.75), 0.75),
])
def test_shapes_and_1khz_sampling(make, duration):
    p = make()
    n = round(duration * RATE_HZ) + 1
    assert len(p) == n
    assert p.t.shape == (n,)
    assert p.q.shape == p.dq.shape == p.ddq.shape == (n, 7)
    assert p.t[0] == 0.0
    np.testing.assert_allclose(np.diff(p.t), H, rtol=0, atol=1e-12)
    assert p.duration == pytest.approx(duration, abs=1e-12)


def test_arrays_are_read_only_copies(excitation):
    with pytest.raises(ValueError):
        excitation.q[0, 0] = 1.0
    q = np.tile(Q0, (3, 1))
    p = Path("x", np.arange(3) / RATE_HZ, q, np.zeros((3, 7)), np.zeros((3, 7)))
    q[0, 0] = 5.0
    assert p.q[0, 0] == 0.0


@pytest.mark.parametrize("field, bad, shape", [
    ("q", np.zeros((3, 6)), "(3, 7)"),
    ("dq", np.zeros((4, 7)), "(3, 7)"),
    ("ddq", np.zeros(21), "(3, 7)"),
    ("t", np.zeros((3, 1)), "(N,)"),
])
def test_bad_shapes_name_the_field(field, bad, shape):
    kw = dict(t=np.arange(3) / RATE_HZ, q=np.tile(Q0, (3, 1)), dq=np.zeros((3, 7)),
              ddq=np.zeros((3, 7)))
    kw[field] = bad
    with pytest.raises(PathError, match=re.escape(f"{field} must have shape {shape}")):
        Path("x", **kw)


def test_time_must_be_1khz_from_zero():
    z = np.zeros((3, 7))
    with pytest.raises(PathError, match="1 kHz from t = 0"):
        Path("x", np.array([0.0, 0.002, 0.004]), z + Q0, z, z)
    with pytest.raises(PathError, match="finite"):
        Path("x", np.arange(3) / RATE_HZ, z + np.nan, z, z)


# -- analytic consistency --------------------------------------------------------------------
def test_excitation_is_analytically_consistent(excitation):
    _assert_consistent(excitation)


def test_new_task_is_analytically_consistent(new_task):
    _assert_consistent(new_task)


# -- limits and boundary conditions ------------------------------------------------------------
@pytest.mark.parametrize("which", ["excitation", "new_task"])
def test_paths_within_limits_with_margin(which, request):
    p = request.getfixturevalue(which)
    m = arm_model()
    assert p.check_limits() is p
    assert np.all(np.abs(p.dq).max(axis=0) <= 0.8 * m.dq_max)
    assert np.all(np.abs(p.ddq).max(axis=0) <= 0.8 * m.ddq_max)
    span = m.q_max - m.q_min
    assert np.all(p.q.min(axis=0) >= m.q_min + 0.05 * span)
    assert np.all(p.q.max(axis=0) <= m.q_max - 0.05 * span)


def test_excitation_starts_and_ends_at_rest_at_q0(excitation):
    np.testing.assert_allclose(excitation.q[0], Q0, atol=1e-12)
    np.testing.assert_allclose(excitation.q[-1], Q0, atol=1e-9)
    assert _at_rest(excitation, 0) and _at_rest(excitation, -1)


def test_excitation_is_rich(excitation):
    assert np.all(np.ptp(excitation.q, axis=0) >= 0.3)
    # every harmonic band is used: the motion is not a single sine per joint
    assert np.all(np.abs(excitation.ddq).max(axis=0) > 0.1)


def test_excitation_is_seeded():
    a, b, c = excitation_path(10.0, seed=3), excitation_path(10.0, seed=3), excitation_path(10.0)
    np.testing.assert_array_equal(a.q, b.q)
    assert not np.allclose(a.q, c.q)


@pytest.mark.parametrize("duration", [1.0, 7.3, 10.0])
def test_excitation_other_durations_stay_in_limits_and_at_rest(duration):
    p = excitation_path(duration, seed=1)
    m = arm_model()
    assert p.duration == pytest.approx(duration)
    assert np.all(np.abs(p.dq) <= 0.8 * m.dq_max)
    assert np.all(np.abs(p.ddq) <= 0.8 * m.ddq_max)
    assert _at_rest(p, 0) and _at_rest(p, -1)
    np.testing.assert_allclose(p.q[-1], Q0, atol=1e-9)


def test_excitation_default_is_two_periods(excitation):
    half = round(EXCITATION_PERIOD * RATE_HZ)
    np.testing.assert_allclose(excitation.q[:half], excitation.q[half:2 * half], atol=1e-9)


def test_new_task_is_quintic_between_its_ends(new_task):
    np.testing.assert_allclose(new_task.q[0], Q_START, atol=1e-12)
    np.testing.assert_allclose(new_task.q[-1], Q_END, atol=1e-12)
    assert _at_rest(new_task, 0) and _at_rest(new_task, -1)
    mid = len(new_task) // 2
    np.testing.assert_allclose(new_task.q[mid], (Q_START + Q_END) / 2, atol=1e-12)
    # peak speed of the minimum-jerk profile: 15/8 of the mean speed, at mid-time
    np.testing.assert_allclose(new_task.dq[mid], 1.875 * (Q_END - Q_START) / 6.0, rtol=1e-12)


def test_linear_and_rest_reject_bad_input():
    with pytest.raises(PathError, match="q_end must have shape"):
        linear_path(Q0, [0.0] * 6, 1.0, "bad")
    with pytest.raises(PathError, match="duration must be > 0"):
        linear_path(Q0, Q_END, 0.0, "bad")
    with pytest.raises(PathError, match="joint 4 position"):
        new_task_path(q_end=[0, 0, 0, 0.5, 0, 2.0, 0])
    with pytest.raises(PathError, match="joint 1 velocity"):
        linear_path(Q0, Q0 + np.array([2.0, 0, 0, 0, 0, 0, 0]), 1.5, "fast")
    with pytest.raises(PathError, match="finite"):
        rest_path([math.nan] * 7, 1.0)


# -- the paper's bags --------------------------------------------------------------------------
@pytest.fixture(scope="module")
def routed(excitation, new_task) -> tuple[int, int]:
    router = BagRouter().route(excitation.q)
    n_excitation = len(router)
    router.route(new_task.q)
    return n_excitation, len(router) - n_excitation


def test_excitation_forms_about_four_bags(routed):
    assert 3 <= routed[0] <= 6  # the paper's excitation path forms 4


def test_new_task_leaves_the_excitation_bags(routed):
    assert routed[1] >= 2


def test_no_new_task_point_falls_inside_an_excitation_bag(excitation, new_task):
    router = BagRouter().route(excitation.q)
    flange = arm_model().flange_positions(new_task.q)
    for q, x in zip(new_task.q, flange, strict=True):
        for qm, xm in zip(router.q_means, router.x_means, strict=True):
            assert not (math.dist(q, qm) < DELTA and math.dist(x, xm) < RHO)




# -- limit violations --------------------------------------------------------------------------
def _with(p: Path, field: str, k: int, j: int, value: float) -> Path:
    arrays = {"q": p.q.copy(), "dq": p.dq.copy(), "ddq": p.ddq.copy()}
    arrays[field][k, j] = value
    return Path("bad", p.t, **arrays)


@pytest.fixture(scope="module")
def short() -> Path:
    return rest_path(Q0, 2.0)


@pytest.mark.parametrize("field, j, value, text", [
    ("q", 3, -0.05, "path 'bad': joint 4 position -0.0500 rad exceeds the upper limit -0.0698 "
                    "rad at t=1.234 s"),
    ("q", 0, -3.0, "joint 1 position -3.0000 rad is below the lower limit -2.8973 rad "
                   "at t=1.234 s"),
    ("dq", 3, 2.3, "path 'bad': joint 4 velocity 2.300 rad/s exceeds the limit 2.175 rad/s "
                   "at t=1.234 s"),
    ("dq", 6, -2.7, "joint 7 velocity -2.700 rad/s is below the limit -2.610 rad/s "
                    "at t=1.234 s"),
    ("ddq", 1, 7.6, "joint 2 acceleration 7.600 rad/s² exceeds the limit 7.500 rad/s² "
                    "at t=1.234 s"),
])
def test_each_limit_violation_names_joint_time_value_and_limit(short, field, j, value, text):
    with pytest.raises(PathError) as err:
        _with(short, field, 1234, j, value).check_limits()
    assert text in str(err.value)
    assert "valid is" in str(err.value)


def test_first_violation_in_time_is_reported(short):
    p = _with(short, "q", 1500, 0, 3.0)  # later position violation
    p = _with(p, "ddq", 200, 5, 25.0)  # earlier acceleration violation
    with pytest.raises(PathError, match=r"joint 6 acceleration .* at t=0\.200 s"):
        p.check_limits()


def test_limits_from_a_given_model(short):
    class Tight:
        q_min, q_max = arm_model().q_min, arm_model().q_max
        dq_max = np.full(7, 1e-3)
        ddq_max = arm_model().ddq_max

    p = _with(short, "dq", 10, 2, 0.01)
    p.check_limits()
    with pytest.raises(PathError, match=r"joint 3 velocity 0\.010 rad/s exceeds the limit 0\.001"):
        p.check_limits(Tight())


# -- then and slice ----------------------------------------------------------------------------
def test_then_joins_excitation_transfer_and_new_task(excitation, new_task):
    transfer = linear_path(Q0, Q_START, 4.0, "transfer")
    p = excitation.then(transfer).then(new_task)
    assert p.name == "excitation+transfer+new-task"
    assert len(p) == len(excitation) + len(transfer) + len(new_task) - 2
    assert p.duration == pytest.approx(30.0)
    np.testing.assert_allclose(np.diff(p.t), H, atol=1e-12)
    np.testing.assert_array_equal(p.q[:len(excitation)], excitation.q)
    np.testing.assert_allclose(p.q[-len(new_task):], new_task.q, rtol=0, atol=1e-12)
    assert excitation.then(transfer, name="both").name == "both"


def test_then_with_rest_before_and_after(new_task):
    p = rest_path(Q_START, 0.5).then(new_task).then(rest_path(Q_END, 0.5))
    assert p.duration == pytest.approx(7.0)
    p.check_limits()
    # the jerk jumps where the pieces meet, so central differences are off by ~ jerk * h / 4
    _assert_consistent(p, rel=1e-3)


def test_then_rejects_a_gap_or_motion(new_task):
    with pytest.raises(PathError, match=r"starts at .* ends at .* within 1e-09 rad"):
        new_task.then(new_task)
    moving = new_task.slice(0.0, 3.0)
    with pytest.raises(PathError, match="'new-task\\[0:3\\]' is not at rest at its end"):
        moving.then(rest_path(moving.q[-1], 1.0))
    with pytest.raises(PathError, match="'bad' is not at rest at its start"):
        rest_path(Q_START, 1.0).then(_with(new_task, "dq", 0, 0, 0.1))


def test_slice(new_task):
    s = new_task.slice(1.0, 2.5)
    assert len(s) == 1501 and s.t[0] == 0.0
    assert s.duration == pytest.approx(1.5)
    np.testing.assert_array_equal(s.q, new_task.q[1000:2501])
    np.testing.assert_array_equal(s.ddq, new_task.ddq[1000:2501])
    assert len(new_task.slice(6.0, 6.0)) == 1
    for t0, t1 in [(-0.1, 1.0), (2.0, 1.0), (0.0, 6.5), (math.nan, 1.0)]:
        with pytest.raises(PathError, match="valid is 0 <= t0 <= t1 <= 6 s"):
            new_task.slice(t0, t1)


# -- CSV files ---------------------------------------------------------------------------------
HEADER = "t,q1,q2,q3,q4,q5,q6,q7"


def _sines(t: np.ndarray):
    """A smooth known motion about Q0 and its derivatives."""
    w = 2 * np.pi * np.array([0.3, 0.5, 0.4, 0.6, 0.7, 0.5, 0.8])
    a = np.array([0.3, 0.2, 0.3, 0.2, 0.3, 0.2, 0.3])
    ph = np.linspace(0.0, 2.0, 7)
    arg = np.outer(t, w) + ph
    return Q0 + a * np.sin(arg), a * w * np.cos(arg), -a * w**2 * np.sin(arg)


def _write(tmp_path, t: np.ndarray, q: np.ndarray, name: str = "p.csv"):
    f = tmp_path / name
    f.write_text(HEADER + "\n" + "".join(
        ",".join(repr(float(v)) for v in (ti, *qi)) + "\n" for ti, qi in zip(t, q, strict=True)))
    return f


def test_csv_round_trip(tmp_path, excitation):
    p = excitation.slice(2.0, 4.0)
    f = tmp_path / "exc.csv"
    save_path_csv(p, f)
    assert f.read_text().splitlines()[0] == HEADER
    back = load_path_csv(f)
    assert back.name == "exc"
    assert len(back) == len(p)
    np.testing.assert_array_equal(back.t, p.t)
    np.testing.assert_allclose(back.q, p.q, rtol=0, atol=1e-9)
    inner = slice(20, -20)  # away from the spline's end conditions
    np.testing.assert_allclose(back.dq[inner], p.dq[inner], rtol=0, atol=1e-6)
    np.testing.assert_allclose(back.ddq[inner], p.ddq[inner], rtol=0, atol=1e-3)


def test_csv_round_trip_through_open_files(new_task):
    buf = io.StringIO()
    save_path_csv(new_task.slice(0.0, 1.0), buf)
    buf.seek(0)
    back = load_path_csv(buf, name="mem")
    assert back.name == "mem"
    np.testing.assert_allclose(back.q, new_task.q[:1001], atol=1e-9)


def test_csv_at_100hz_is_resampled_to_1khz(tmp_path):
    t_file = np.arange(301) * 0.01  # 3 s at 100 Hz
    q_file, _, _ = _sines(t_file)
    p = load_path_csv(_write(tmp_path, t_file, q_file))
    assert len(p) == 3001
    q, dq, ddq = _sines(p.t)
    np.testing.assert_allclose(p.q, q, atol=1e-6)
    inner = slice(50, -50)
    np.testing.assert_allclose(p.dq[inner], dq[inner], atol=1e-4)
    np.testing.assert_allclose(p.ddq[inner], ddq[inner], atol=1e-2)
    np.testing.assert_allclose(p.dq, dq, atol=1e-3)
    _assert_consistent(p, rel=1e-3)


def test_csv_at_irregular_rate_and_offset_start(tmp_path):
    rng = np.random.default_rng(7)
    t_file = 5.0 + np.concatenate(([0.0], np.cumsum(rng.uniform(0.002, 0.01, 400))))
    q_file, _, _ = _sines(t_file)
    p = load_path_csv(_write(tmp_path, t_file, q_file, "irregular.csv"))
    assert p.t[0] == 0.0
    assert p.duration == pytest.approx(t_file[-1] - t_file[0], abs=H)
    q, dq, _ = _sines(p.t + 5.0)
    np.testing.assert_allclose(p.q, q, atol=1e-6)
    np.testing.assert_allclose(p.dq[50:-50], dq[50:-50], atol=1e-4)


def test_csv_header_tolerates_spaces(tmp_path):
    t = np.arange(5) * 0.01
    f = tmp_path / "spaced.csv"
    rows = "".join(f"{float(ti)!r}," + ",".join(repr(float(v)) for v in Q0) + "\n" for ti in t)
    f.write_text(" t , q1,q2 ,q3,q4,q5,q6, q7\n" + rows + "\n\n")
    p = load_path_csv(f)
    assert p.duration == pytest.approx(0.04)
    np.testing.assert_allclose(p.q, np.tile(Q0, (41, 1)), atol=1e-12)


def _rows(n: int = 5, dt: float = 0.01) -> list[str]:
    return [f"{k * dt!r}," + ",".join(repr(float(v)) for v in Q0) for k in range(n)]


def _replace(rows: list[str], k: int, col: int, text: str) -> list[str]:
    out = list(rows)
    cells = out[k].split(",")
    cells[col - 1] = text
    out[k] = ",".join(cells)
    return out


_ROWS = _rows()
CSV_ERRORS = {
    "empty": ("", "line 1: the header must be exactly 't,q1,q2,q3,q4,q5,q6,q7'"),
    "no header": ("\n".join(_ROWS), "line 1: the header must be exactly"),
    "wrong header": ("\n".join(["t,q1,q2,q3,q4,q5,q6", *_ROWS]),
                     "line 1: the header must be exactly 't,q1,q2,q3,q4,q5,q6,q7'"),
    "non-numeric": ("\n".join([HEADER, *_replace(_ROWS, 2, 4, "abc")]),
                    "line 4, column 4 (q3): 'abc' is not a number; expected a finite number "
                    "in rad"),
    "empty cell": ("\n".join([HEADER, *_replace(_ROWS, 1, 1, " ")]),
                   "line 3, column 1 (t): '' is not a number"),
    "nan": ("\n".join([HEADER, *_replace(_ROWS, 3, 8, "nan")]),
            "line 5, column 8 (q7): 'nan' is not finite; expected a finite number in rad"),
    "inf": ("\n".join([HEADER, *_replace(_ROWS, 0, 2, "-inf")]),
            "line 2, column 2 (q1): '-inf' is not finite"),
    "too few columns": ("\n".join([HEADER, _ROWS[0], _ROWS[1].rsplit(",", 1)[0], *_ROWS[2:]]),
                        "line 3: expected 8 columns (t,q1,q2,q3,q4,q5,q6,q7), got 7"),
    "too many columns": ("\n".join([HEADER, *_ROWS[:4], _ROWS[4] + ",0.0"]),
                         "line 6: expected 8 columns (t,q1,q2,q3,q4,q5,q6,q7), got 9"),
    "t repeats": ("\n".join([HEADER, *_replace(_ROWS, 2, 1, "0.01")]),
                  "line 4, column 1 (t): t = 0.01 s does not increase after t = 0.01 s on line "
                  "3; t must be strictly increasing"),
    "t decreases": ("\n".join([HEADER, *_replace(_ROWS, 3, 1, "0.0")]),
                    "line 5, column 1 (t): t = 0.0 s does not increase"),
    "slow rate": ("\n".join([HEADER, *_rows(5, 0.02)]),
                  "line 3, column 1 (t): the interval 0.02 s since line 2 is a rate of 50 Hz; "
                  "a path file needs at least 100 Hz (every interval <= 0.01 s)"),
    "one gap": ("\n".join([HEADER, *_ROWS[:3], *_replace(_ROWS, 3, 1, "0.045")[3:4]]),
                "line 5, column 1 (t): the interval 0.025 s since line 4 is a rate of 40 Hz"),
    "too few rows": ("\n".join([HEADER, *_ROWS[:3]]) + "\n",
                     "line 5: the file ends after 3 data row(s); a path file needs at least 4 "
                     "rows"),
    # joint 4 ramps up at 1 rad/s and crosses its upper limit -0.0698 rad at t = 0.1302 s
    "out of limits": ("\n".join([HEADER, *(_replace(_rows(30), k, 5, repr(-0.2 + 0.01 * k))[k]
                                            for k in range(30))]),
                      "near line 15: path 'bad': joint 4 position -0.0690 rad exceeds the upper "
                      "limit -0.0698 rad at t=0.131 s"),
}


@pytest.mark.parametrize("case", list(CSV_ERRORS))
def test_csv_errors_name_file_line_and_what_is_valid(tmp_path, case):
    text, expected = CSV_ERRORS[case]
    f = tmp_path / "bad.csv"
    f.write_text(text)
    with pytest.raises(PathError) as err:
        load_path_csv(f)
    message = str(err.value)
    assert message.startswith(f"{f}, ")
    assert expected in message


def test_csv_unreadable_files(tmp_path):
    missing = tmp_path / "missing.csv"
    with pytest.raises(PathError, match=r"missing\.csv: cannot read the path file: it does "
                                        "not exist"):
        load_path_csv(missing)
    with pytest.raises(PathError, match="cannot read the path file: it is a directory"):
        load_path_csv(tmp_path)  # a folder
    fifo = tmp_path / "fifo.csv"  # once a read that waited for a writer for good
    os.mkfifo(fifo)
    with within(10), pytest.raises(PathError, match="it is a FIFO"):
        load_path_csv(fifo)
    binary = tmp_path / "binary.csv"
    binary.write_bytes(b"\xff\xfe\x00t,q1")
    with pytest.raises(PathError, match="not UTF-8 text"):
        load_path_csv(binary)


def test_csv_with_byte_order_mark_and_crlf(tmp_path):
    f = tmp_path / "excel.csv"
    f.write_bytes(("\ufeff" + HEADER + "\r\n" + "\r\n".join(_rows(6)) + "\r\n").encode())
    p = load_path_csv(f)
    assert p.duration == pytest.approx(0.05)


def test_a_csv_is_checked_against_the_arm_model_it_is_for(tmp_path):
    """An FR3 path faster than the Panda's limits allow (its wrist turns at 4.18 rad/s, the
    Panda's at 2.61) loads for the FR3 and is refused for the Panda."""
    from sim.robot import ArmModel

    fr3 = ArmModel(description="fr3")
    q0 = np.array(fr3.description.home)
    q1 = q0.copy()
    q1[5] += 1.6  # joint 6: a quintic's peak speed 1.875 x 1.6 / 1 s = 3.0 rad/s
    path = linear_path(q0, q1, 1.0, model=fr3)
    f = tmp_path / "fr3.csv"
    save_path_csv(path, f)
    assert load_path_csv(f, model=fr3).duration == pytest.approx(1.0)
    with pytest.raises(PathError, match="joint 6 velocity"):
        load_path_csv(f)
