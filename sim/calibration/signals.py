"""Step 1 of the calibration: the traffic through the one offline signal chain
(:func:`iem.signals.offline.prepare`: split at its gaps, resampled where its clock jitters,
spikes out, zero-phase filtered, differentiated, trimmed and decimated) with the
calibration's settings."""

from __future__ import annotations

from iem.errors import InvalidInputError
from iem.signals.offline import JITTER_TOL, MAX_GAP_S, Signals, prepare, segments
from iem.signals.recording import Recording

from .prior import DEFAULT_SETTINGS, CalibrationError, CalibrationSettings

__all__ = ["JITTER_TOL", "MAX_GAP_S", "calibration_signals", "min_piece_s", "segments"]


def min_piece_s(s: CalibrationSettings = DEFAULT_SETTINGS) -> float:
    """The shortest gap-free piece of traffic a calibration uses, s: ``trim_s`` dropped at
    both ends still leaves twice that and 2 s of motion."""
    return 4.0 * s.trim_s + 2.0


def calibration_signals(parts, s: CalibrationSettings = DEFAULT_SETTINGS) -> list[Signals]:
    """Each recording of ``parts`` (``[(t, q, dq, tau), ...]``, s, rad, rad/s, N·m) prepared
    with ``s.cutoff_hz``, ``s.rate_hz``, ``s.trim_s`` and ``s.recorded_rate_hz``; pieces
    shorter than :func:`min_piece_s` are left out.

    Raises:
        CalibrationError: a recording is malformed or holds no piece long enough, or the
            cut-off or the rate does not suit its recorded rate.
    """
    out = []
    for k, part in enumerate(parts):
        what = "traffic" if len(parts) == 1 else f"traffic {k + 1} of {len(parts)}"
        try:
            out.append(prepare(Recording(*part), s.cutoff_hz, s.rate_hz, s.trim_s,
                               min_s=min_piece_s(s), what=what,
                               recorded_rate_hz=s.recorded_rate_hz))
        except InvalidInputError as exc:
            raise CalibrationError(f"{exc}; record the calibration motion "
                                   f"(sim.paths.calibration_path, 30 s)") from exc
    return out
