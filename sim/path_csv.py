"""Path CSV files: a joint path as ``t,q1..q7`` rows, read (resampled to 1 kHz and checked)
and written.

Path CSV files (:func:`load_path_csv`, :func:`save_path_csv`)::

    t,q1,q2,q3,q4,q5,q6,q7
    0.0,0.0,-0.3,0.0,-2.2,0.0,2.0,0.8
    0.01,...

- the header is exactly ``t,q1,q2,q3,q4,q5,q6,q7`` (spaces around the names are allowed);
- ``t`` in s, strictly increasing, every interval at most 0.01 s (a rate of at least 100 Hz);
- ``q1..q7`` in rad; every value a finite number; at least 4 data rows; blank lines ignored;
  UTF-8 text (a leading byte-order mark is allowed).

A loaded file is shifted to start at t = 0 and resampled to 1 kHz up to its last sample with a
not-a-knot cubic spline per joint (``scipy.interpolate.CubicSpline``); ``dq`` and ``ddq`` are
the spline's derivatives. Then the limits are checked. Every problem raises
:class:`~iem.errors.PathError` naming the file, the line (1-based, the header is line 1), the
column where relevant, and what would be valid.
"""

from __future__ import annotations

import math
import os
from pathlib import Path as FsPath

import numpy as np

from iem.errors import PathError
from iem.user_files import read_text

from .joint_path import RATE_HZ, TIME_TOL, Path

CSV_HEADER = ("t", "q1", "q2", "q3", "q4", "q5", "q6", "q7")
MIN_CSV_RATE_HZ = 100.0
"""Lowest sample rate a path file may have, Hz."""
MIN_CSV_ROWS = 4
MAX_PATH_FILE_BYTES = 64 * 1024 * 1024
"""Largest path file read (a planned path of minutes at 1 kHz is a few MB)."""


def _read_text(file) -> tuple[str, str]:
    """``(text, name for messages)`` of a path-like or an open text file."""
    if hasattr(file, "read"):
        where = str(getattr(file, "name", "<stream>"))
        try:
            text = file.read()
        except (OSError, UnicodeDecodeError) as exc:
            raise PathError(f"{where}: cannot read path file: {exc}") from exc
        if isinstance(text, bytes):
            try:
                text = text.decode("utf-8")
            except UnicodeDecodeError as exc:
                raise PathError(f"{where}: path file is not UTF-8 text: {exc}") from exc
        return text.removeprefix("\ufeff"), where
    where = os.fspath(file)  # a regular file, within bounds
    return read_text(where, MAX_PATH_FILE_BYTES, "path file", PathError,
                     encoding="utf-8-sig"), str(where)


def _parse_csv(text: str, where: str) -> tuple[np.ndarray, np.ndarray]:
    """``(data (M, 8), line number of each row)`` of a path CSV, every problem a PathError."""
    expected = ",".join(CSV_HEADER)
    lines = text.splitlines()
    if not lines or [c.strip() for c in lines[0].split(",")] != list(CSV_HEADER):
        got = repr(lines[0]) if lines else "an empty file"
        raise PathError(f"{where}, line 1: the header must be exactly {expected!r} "
                        f"(t in s, q1..q7 in rad), got {got}")
    rows, numbers = [], []
    prev_t, prev_line = None, 1
    max_dt = 1.0 / MIN_CSV_RATE_HZ
    for line_no, line in enumerate(lines[1:], start=2):
        if not line.strip():
            continue
        cells = line.split(",")
        if len(cells) != len(CSV_HEADER):
            raise PathError(f"{where}, line {line_no}: expected {len(CSV_HEADER)} columns "
                            f"({expected}), got {len(cells)}")
        row = []
        for col, (cell, field) in enumerate(zip(cells, CSV_HEADER, strict=True), start=1):
            unit = "s" if field == "t" else "rad"
            try:
                value = float(cell)
            except ValueError:
                raise PathError(f"{where}, line {line_no}, column {col} ({field}): "
                                f"{cell.strip()!r} is not a number; expected a finite number "
                                f"in {unit}") from None
            if not math.isfinite(value):
                raise PathError(f"{where}, line {line_no}, column {col} ({field}): "
                                f"{cell.strip()!r} is not finite; expected a finite number "
                                f"in {unit}")
            row.append(value)
        t = row[0]
        if prev_t is not None:
            dt = t - prev_t
            if dt <= 0.0:
                raise PathError(f"{where}, line {line_no}, column 1 (t): t = {t!r} s does not "
                                f"increase after t = {prev_t!r} s on line {prev_line}; "
                                "t must be strictly increasing")
            if dt > max_dt + TIME_TOL:
                raise PathError(f"{where}, line {line_no}, column 1 (t): the interval "
                                f"{dt:.6g} s since line {prev_line} is a rate of "
                                f"{1.0 / dt:.4g} Hz; a path file needs at least "
                                f"{MIN_CSV_RATE_HZ:g} Hz (every interval <= {max_dt:g} s)")
        prev_t, prev_line = t, line_no
        rows.append(row)
        numbers.append(line_no)
    if len(rows) < MIN_CSV_ROWS:
        raise PathError(f"{where}, line {len(lines) + 1}: the file ends after {len(rows)} data "
                        f"row(s); a path file needs at least {MIN_CSV_ROWS} rows after the "
                        "header")
    return np.array(rows), np.array(numbers)


def load_path_csv(file, name: str | None = None, model=None) -> Path:
    """Read a path CSV file (see the module docstring), resample it to 1 kHz and check the
    limits of the arm model ``model`` (a :class:`sim.robot.ArmModel`; None: the default
    arm model's).

    ``file`` is a file system path or an open text file. The path is named ``name`` or the
    file's stem. Raises :class:`PathError` naming the file, line and column of any problem.
    """
    from scipy.interpolate import CubicSpline

    text, where = _read_text(file)
    data, line_numbers = _parse_csv(text, where)
    t_file = data[:, 0] - data[0, 0]
    spline = CubicSpline(t_file, data[:, 1:], axis=0, bc_type="not-a-knot")
    t = np.arange(math.floor(t_file[-1] * RATE_HZ + 1e-6) + 1) / RATE_HZ
    path = Path(name=name if name is not None else FsPath(where).stem, t=t, q=spline(t),
                dq=spline(t, 1), ddq=spline(t, 2))
    found = path.first_violation(model)
    if found is not None:
        k, message = found
        line = int(line_numbers[int(np.argmin(np.abs(t_file - t[k])))])
        raise PathError(f"{where}, near line {line}: {message} (after resampling to 1 kHz)")
    return path


def save_path_csv(path: Path, file) -> None:
    """Write ``t,q1..q7`` (s, rad) at full precision; :func:`load_path_csv` reads it back.

    ``file`` is a file system path or an open text file."""
    out = [",".join(CSV_HEADER)]
    out += [",".join(repr(float(v)) for v in (t, *q)) for t, q in zip(path.t, path.q,
                                                                      strict=True)]
    text = "\n".join(out) + "\n"
    if hasattr(file, "write"):
        file.write(text)
    else:
        FsPath(file).write_text(text, encoding="utf-8")
