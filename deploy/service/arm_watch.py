"""A watch on the arm model: a payload estimate clearly below zero mass says the model is wrong.

No payload weighs less than nothing. When the estimate of a bare or light load sits clearly
below zero for a while, the arm model the plug-in runs with does not match the arm: most often
a wrong end effector (a bare arm through the Franka Hand's model reads about -0.7 kg: set
``[arm] end_effector``), or an arm that was never calibrated (``iem calibrate``). The gate
refuses such estimates anyway (``inconsistent``); this says why, once, in the log (event
``arm_mismatch``) and in the summary.

The mass watched is the model's own before any projection onto possible bodies (IEM+phys's
``mean_mass``: its projected estimate never goes below zero), else the smoothed one.
"Clearly" is: that mass below ``-max(MIN_NEGATIVE_KG, 2 std)`` (the raw estimate's
standard deviation, where the model gives one) for :data:`HOLD_S` seconds of controller time.
"""

from __future__ import annotations

import logging
import math

from iem.types import PayloadEstimate

log = logging.getLogger("iem.service")

MIN_NEGATIVE_KG = 0.05
"""A mass below minus this (and below minus two standard deviations) is clearly negative, kg."""
HOLD_S = 3.0
"""How long the mass must stay clearly negative before the watch speaks, s."""

MESSAGE = ("the payload estimate has stayed at {mass:.3f} kg, below zero, for {held:.1f} s: "
           "the arm model does not match the arm. Check the end effector ([arm] end_effector "
           "or --end-effector: franka_hand, none or the tool's file, as set in Franka Desk) "
           "and calibrate the arm on bare-arm motion ('iem calibrate')")


class ArmWatch:
    """Watches the estimates for a mass that stays clearly below zero (module docstring)."""

    def __init__(self, hold_s: float = HOLD_S, min_negative_kg: float = MIN_NEGATIVE_KG) -> None:
        self.hold_s = float(hold_s)
        self.min_negative_kg = float(min_negative_kg)
        self._since: float | None = None
        self.finding: dict | None = None
        """None, or what the watch found: ``{"t", "mass_kg", "held_s", "message"}``."""

    def observe(self, t: float, smoothed, raw=None) -> None:
        """One estimate at controller time ``t`` (s): the smoothed phi and the raw estimate."""
        if self.finding is not None:
            return
        extra = raw.extra if isinstance(raw, PayloadEstimate) else {}
        mass = float(extra.get("mean_mass", smoothed[0]))  # IEM+phys: before its projection
        std = raw.std if isinstance(raw, PayloadEstimate) else None
        sigma = 0.0 if std is None or not math.isfinite(std[0]) else float(std[0])
        if not mass < -max(self.min_negative_kg, 2.0 * sigma):
            self._since = None
            return
        if self._since is None:
            self._since = t
        held = t - self._since
        if held >= self.hold_s:
            message = MESSAGE.format(mass=mass, held=held)
            self.finding = {"t": t, "mass_kg": mass, "held_s": held, "message": message}
            log.warning(message, extra={"event": "arm_mismatch", "mass_kg": mass})
