"""The safety gate's checks of one estimate on its own: its contract (shapes, signs, age),
what it is (finite, a possible rigid body, within the robot's rating with the end effector and
its reach, within the wire's ranges) and what the model says of it (its verdicts, the
agreement of the data, the inertia's band). The gate (:mod:`deploy.writeback.gate`) adds what
depends on time and on the controller: the load in force, commands, stability, whether a write
helps, and rate. Every check returns a reason and its detail, never raises, whatever it is given.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from iem.payload import Payload

if TYPE_CHECKING:
    from .settings import GateConfig

WireCheck = Callable[[Payload], "str | None"]
"""A link's range check of a load: why its wire format cannot carry it, or None."""


def check_estimate(phi: np.ndarray, config: GateConfig, wire_check: WireCheck | None = None
                   ) -> tuple[str, str]:
    """``(reason, detail)`` of the estimate ``phi`` (paper order): ``reason`` is ``""`` when
    it may be written as far as its values go, else ``not_finite``, ``inconsistent``,
    ``over_rated`` (the payload and the declared end effector together beyond the arm's
    rated payload), ``com_too_far``, ``out_of_wire_range`` or ``malformed`` (not 10
    values)."""
    c = config
    if phi.shape != (10,):
        return "malformed", f"phi has shape {phi.shape}, valid is (10,)"
    if not np.all(np.isfinite(phi)):
        return "not_finite", "estimate has NaN or infinite values"
    if not phi[0] > 0.0:
        return "inconsistent", f"mass {phi[0]:.4g} kg is not > 0"
    payload = Payload.from_phi(phi, name="estimate")
    problems = payload.consistency_violations()
    if problems:
        return "inconsistent", "; ".join(problems)
    if payload.mass + c.end_effector_mass_kg > c.rated_mass_kg:
        return "over_rated", (
            f"mass {payload.mass:.3f} kg + end effector {c.end_effector_mass_kg:.3f} kg > "
            f"rated {c.rated_mass_kg:g} kg")
    radius = math.sqrt(sum(v * v for v in payload.com))
    if radius > c.max_com_radius_m:
        return "com_too_far", f"CoM {radius:.3f} m from the flange > {c.max_com_radius_m:g} m"
    if wire_check is not None:
        why = wire_check(payload)
        if why:
            return "out_of_wire_range", f"the link's wire format cannot carry it: {why}"
    return "", ""


def contract(estimate, t: float, age_s: float, config: GateConfig) -> tuple[str, str] | None:
    """``(reason, detail)`` if the raw estimate breaks its contract, else None:
    ``malformed`` (not a :class:`iem.types.PayloadEstimate`-shaped value: ``phi`` not 10
    numbers, ``std`` not None nor 10 numbers, a negative or NaN ``std``, a negative ``nis``, a
    time that is not a number) or ``stale`` (older than ``max_age_s`` at the decision time
    ``t``: ``age_s``). Estimates that are not PayloadEstimates at all are left to
    :func:`model_doubt` (``unreported``)."""
    from iem.types import PayloadEstimate

    if not isinstance(estimate, PayloadEstimate):
        return None
    try:
        phi = np.asarray(estimate.phi, dtype=float)
        std = None if estimate.std is None else np.asarray(estimate.std, dtype=float)
        nis = None if estimate.nis is None else float(estimate.nis)
        when = float(estimate.t)
    except (TypeError, ValueError) as exc:
        return "malformed", f"the estimate's fields are not numbers: {exc}"
    if phi.shape != (10,):
        return "malformed", f"phi has shape {phi.shape}, valid is (10,)"
    if std is not None:
        if std.shape != (10,):
            return "malformed", f"std has shape {std.shape}, valid is (10,) or None"
        if np.isnan(std).any() or (std < 0).any():
            return "malformed", f"std has a negative or NaN entry ({_worst(std)}); valid is >= 0"
    if estimate.cov is not None:
        try:
            cov = np.asarray(estimate.cov, dtype=float)
        except (TypeError, ValueError):
            return "malformed", "cov is not numbers; valid is a 10x10 covariance or None"
        if cov.shape != (10, 10):
            return "malformed", f"cov has shape {cov.shape}, valid is (10, 10) or None"
    if nis is not None and nis < 0:
        return "malformed", f"nis {nis:.4g} is negative; valid is >= 0 or NaN (no verdict yet)"
    if not math.isfinite(when):
        return "malformed", f"the estimate's time {when!r} is not a number"
    flags = {"ood": estimate.ood, "unverified": estimate.unverified}
    for name, value in flags.items():
        if not (value is None or isinstance(value, bool | np.bool_)):
            return "malformed", f"{name} is {type(value).__name__}; valid is True, False or None"
    determined = estimate.determined
    if determined is not None and not (isinstance(determined, tuple)
                                       and all(isinstance(g, str) for g in determined)):
        return "malformed", "determined is not None nor a tuple of group names"
    if not age_s <= config.max_age_s:
        return "stale", (f"the estimate is {age_s:.3g} s old at t = {t:.3f} s > "
                         f"{config.max_age_s:g} s")
    return None


def _worst(std: np.ndarray) -> str:
    bad = np.flatnonzero(np.isnan(std) | (std < 0))
    return ", ".join(f"std[{i}] = {std[i]:.4g}" for i in bad[:3])


def model_doubt(estimate, config: GateConfig) -> tuple[str, str] | None:
    """``(reason, detail)`` if the model's own figures say its estimate (an
    :class:`iem.types.PayloadEstimate`, already through :func:`contract`) is not fit to
    write, else None. It fails closed: what it needs and the estimate does not report holds
    the write back.

    - ``unreported``: the estimate is not a :class:`iem.types.PayloadEstimate`, or it does
      not report its standard deviations (``std``), its data's verdict (``nis``) or its
      out-of-distribution verdict (``ood``): None for any of them. Unless the cell allows
      writing without them (``allow_without_uncertainty``; the paper's IEM needs it): then
      what is reported is still checked;
    - ``out_of_distribution``: ``ood``: the IEM's learner met an input far beyond its bag's
      training inputs (:meth:`iem.ensemble.IncrementalEnsemble.ood_score`);
    - ``unverified``: the estimate started from a payload file or from a restored state (a
      restart) and the model has not yet tested it against enough live data;
    - ``uncertain``: the data do not determine the mass or the CoM (the model's
      ``determined``: they are its prior's guess), the mass's or the first moment's band is
      not a number (infinite: no band known), or the inertia's 2-sigma band is wider than
      ``max_inertia_2sigma_kgm2`` while the data determine the inertia (one the data do not
      determine is written as the prior has it, and the write says so);
    - ``data_disagree``: ``nis`` (the mean normalised innovation squared per degree of
      freedom over the model's recent equations, about 1 when the data agree with the
      model) exceeds ``max_nis``; a NaN ``nis`` (no equation tested yet) does not hold a
      write back, but the estimate is then its prior's, which the gate's comparison with
      the load in force judges by its band.
    """
    from iem.types import PayloadEstimate

    if not isinstance(estimate, PayloadEstimate):
        if config.allow_without_uncertainty and estimate is None:
            return None
        return ("unreported", f"the model gave {type(estimate).__name__}, not a "
                              "PayloadEstimate: nothing says how good it is")
    missing = [name for name, value in (("std", estimate.std), ("nis", estimate.nis),
                                        ("ood", estimate.ood)) if value is None]
    if missing and not config.allow_without_uncertainty:
        return ("unreported", f"the model does not report {', '.join(missing)}; set [gate] "
                              "allow_without_uncertainty = true to write without them")
    if estimate.ood:
        extra = estimate.extra if isinstance(estimate.extra, dict) else {}
        why = (f"the learner's input lies {extra.get('ood_score', 0):.3g} standard deviations "
               "beyond what its bag was trained on")
        if "velocity_score" in extra:
            why += (f" (its joint velocities score {extra['velocity_score']:.3g} against the "
                    "bag's training velocities)")
        return ("out_of_distribution", why)
    if estimate.unverified:
        return ("unverified", "the estimate starts from a payload file or a restored state "
                              "and has not yet been tested against enough live data")
    determined = estimate.determined
    if determined is not None and not {"mass", "com"} <= set(determined):
        missing = " and ".join(g for g in ("mass", "com") if g not in determined)
        settle = (estimate.extra or {}).get("settle")  # what motion would (the model's)
        return ("uncertain", f"the data do not determine the {missing} yet: it is the "
                             "prior's guess, not a measurement"
                             + (f"; {settle}" if settle else ""))
    if estimate.std is not None:
        wide = _band_unusable(np.asarray(estimate.std, dtype=float), estimate, config)
        if wide is not None:
            return ("uncertain", wide)
    nis = estimate.nis
    if nis is not None and not math.isnan(nis) and not nis <= config.max_nis:
        return ("data_disagree", f"normalised innovation squared {nis:.3g} per degree of "
                                 f"freedom > {config.max_nis:g}: the data disagree with the model")
    return None


def _band_unusable(std: np.ndarray, estimate, config: GateConfig) -> str | None:
    """Why the estimate's band cannot bound a write, or None."""
    if not np.isfinite(std[:4]).all():
        return "no band on the mass or the first moment (an infinite standard deviation)"
    determined = estimate.determined
    if determined is not None and "inertia" not in determined:
        return None  # written as the prior has it, said so in the send's detail
    band = 2.0 * float(std[4:].max())
    if not band <= config.max_inertia_2sigma_kgm2:
        return (f"2-sigma band on the inertia {band:.4g} kg·m² > "
                f"{config.max_inertia_2sigma_kgm2:g} kg·m²")
    return None


def upper_mass(phi, std) -> float:
    """The mass's upper 2-sigma bound, kg (inf without a band)."""
    if std is None:
        return math.inf
    return float(phi[0]) + 2.0 * float(std[0])
