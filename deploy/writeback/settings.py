"""The safety gate's settings: :class:`GateConfig`, which checks itself against
:data:`RANGES` (``cell.toml``'s ``[gate]`` checks the same ranges). ``docs/decisions.md``
gives the sources of the defaults."""

from __future__ import annotations

from dataclasses import dataclass, fields

from iem.errors import InvalidInputError

RANGES: dict[str, tuple[float, float]] = {
    "rated_mass_kg": (0.01, 50.0),
    "end_effector_mass_kg": (0.0, 50.0),
    "max_com_radius_m": (0.001, 1.0),
    "stable_window_s": (0.01, 60.0),
    "stable_mass_kg": (0.0, 3.0),
    "stable_com_m": (0.0, 1.0),
    "write_margin": (0.01, 1.0),
    "min_torque_error_nm": (0.0, 100.0),
    "max_inertia_2sigma_kgm2": (1e-6, 10.0),
    "max_age_s": (0.001, 60.0),
    "reach_m": (0.05, 5.0),
    "max_rate_hz": (0.001, 100.0),
    "ack_timeout_s": (0.01, 60.0),
    "ack_retry_s": (0.05, 3600.0),
    "ack_retry_max_s": (0.05, 3600.0),
    "decision_period_s": (0.001, 10.0),
    "max_nis": (1.0, 1e6),
    "refusal_retry_s": (0.1, 3600.0),
    "refusal_retry_max_s": (0.1, 3600.0),
    "max_disagreements": (1, 100),
}
"""The valid range of every numeric setting (``cell.toml``'s ``[gate]`` checks the same)."""


@dataclass(frozen=True)
class GateConfig:
    """Safety-gate settings (units in the names); ``docs/decisions.md`` gives the sources of
    the defaults. It checks itself: a value outside :data:`RANGES` raises
    :class:`iem.errors.InvalidInputError` naming the valid range.

    Attributes:
        rated_mass_kg: the arm's rated payload: payload plus end effector never exceed it.
        end_effector_mass_kg: the declared end effector's mass (``[arm] end_effector``).
        max_com_radius_m: largest distance of the CoM from the flange origin.
        stable_window_s: how long the estimate must stay within the band to count as stable.
        stable_mass_kg, stable_com_m: the stability band (spread over the window).
        write_margin: a write goes out only if its worst-case joint-torque error is at most
            this share of the least error the load in force has.
        min_torque_error_nm: a load in force that errs by less than this (N·m, at the worst
            joint and pose of the recent motion, beyond the estimate's band) is kept.
        max_inertia_2sigma_kgm2: no write while the data determine the inertia and its
            2-sigma band is wider than this.
        max_age_s: no write of an estimate older than this at the decision.
        reach_m: the arm's reach, for the torque bound before any motion is seen.
        max_rate_hz: at most this many writes per second (a write the controller refused
            does not count: the refusal's back-off paces its retry).
        ack_timeout_s: a command unanswered this long is lost.
        ack_retry_s, ack_retry_max_s: the wait after a lost command, doubling, up to the max.
        decision_period_s: how often the gate decides.
        max_nis: no write while the model's ``nis`` exceeds this.
        allow_without_uncertainty: write estimates that do not report ``std``, ``nis`` or
            ``ood`` (the paper's IEM); by default they are held back (``unreported``).
        refusal_retry_s, refusal_retry_max_s: the wait after a refusal, doubling, up to the max.
        max_disagreements: a controller whose own report contradicts a load it had
            confirmed this many times in a row is not written to again until it reports
            another load (``controller_disagrees``); each such write waits the refusal's
            back-off first.
    """

    rated_mass_kg: float = 3.0
    end_effector_mass_kg: float = 0.0
    max_com_radius_m: float = 0.15
    stable_window_s: float = 0.5
    stable_mass_kg: float = 0.02
    stable_com_m: float = 0.004
    write_margin: float = 1.0
    min_torque_error_nm: float = 0.015
    max_inertia_2sigma_kgm2: float = 0.05
    max_age_s: float = 1.0
    reach_m: float = 0.855
    max_rate_hz: float = 1.0
    ack_timeout_s: float = 0.5
    ack_retry_s: float = 0.5
    ack_retry_max_s: float = 10.0
    decision_period_s: float = 0.05
    max_nis: float = 3.0
    allow_without_uncertainty: bool = False
    refusal_retry_s: float = 1.0
    refusal_retry_max_s: float = 10.0
    max_disagreements: int = 5

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name == "allow_without_uncertainty":
                if not isinstance(value, bool):
                    raise InvalidInputError(f"GateConfig.{f.name} = {value!r}: valid is a bool")
                continue
            lo, hi = RANGES[f.name]
            if isinstance(lo, int) and isinstance(hi, int):
                if isinstance(value, bool) or not isinstance(value, int) or not (
                        lo <= value <= hi):
                    raise InvalidInputError(f"GateConfig.{f.name} = {value!r} is out of "
                                            f"range; valid is an integer from {lo} to {hi}")
                continue
            if isinstance(value, bool) or not isinstance(value, int | float) or not (
                    lo <= value <= hi):
                raise InvalidInputError(f"GateConfig.{f.name} = {value!r} is out of range; "
                                        f"valid is {lo:g} to {hi:g}")
        for first, most in (("refusal_retry_s", "refusal_retry_max_s"),
                            ("ack_retry_s", "ack_retry_max_s")):
            if getattr(self, most) < getattr(self, first):
                raise InvalidInputError(f"GateConfig.{most} = {getattr(self, most)!r} is below "
                                        f"{first} = {getattr(self, first)!r}; valid is "
                                        f"{most} >= {first}")
