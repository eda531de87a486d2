"""The safety gate's checks of one estimate on its own: what it is (finite, a possible rigid
body, within the robot's rating and reach, within the wire's ranges) and what the model says
of it (its uncertainty, the agreement of the data). The gate (:mod:`deploy.gate`) adds what
depends on time: the controller's state, acknowledgements and refusals, stability, change
and rate.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from iem.payload import Payload

if TYPE_CHECKING:
    from .gate import GateConfig

WireCheck = Callable[[Payload], "str | None"]
"""A link's range check of a load: why its wire format cannot carry it, or None."""


def check_estimate(phi: np.ndarray, config: GateConfig, wire_check: WireCheck | None = None
                   ) -> tuple[Payload | None, str, str]:
    """``(payload, reason, detail)`` of the estimate ``phi`` (paper order): ``reason`` is
    ``""`` when it may be written as far as its values go, else ``not_finite``,
    ``inconsistent``, ``over_rated``, ``com_too_far`` or ``out_of_wire_range``; ``payload``
    is None while ``phi`` has no recoverable CoM."""
    c = config
    if phi.shape != (10,) or not np.all(np.isfinite(phi)):
        return None, "not_finite", "estimate has NaN or infinite values"
    if not phi[0] > 0.0:
        return None, "inconsistent", f"mass {phi[0]:.4g} kg is not > 0"
    payload = Payload.from_phi(phi, name="estimate")
    problems = payload.consistency_violations()
    if problems:
        return payload, "inconsistent", "; ".join(problems)
    if payload.mass > c.rated_mass_kg:
        return payload, "over_rated", f"mass {payload.mass:.3f} kg > rated {c.rated_mass_kg:g} kg"
    radius = math.sqrt(sum(v * v for v in payload.com))
    if radius > c.max_com_radius_m:
        return (payload, "com_too_far",
                f"CoM {radius:.3f} m from the flange > {c.max_com_radius_m:g} m")
    if wire_check is not None:
        why = wire_check(payload)
        if why:
            return payload, "out_of_wire_range", f"the link's wire format cannot carry it: {why}"
    return payload, "", ""


def com_2sigma(phi, std) -> float:
    """The 2-sigma radius of the CoM, m, of an estimate ``phi`` (paper order) with standard
    deviations ``std``: ``r = (m r) / m`` to first order, NaN where it is not defined."""
    phi = np.asarray(phi, dtype=float).reshape(-1)
    std = np.asarray(std, dtype=float).reshape(-1)
    mass = phi[0]
    if not mass > 0.0:
        return math.nan
    com = phi[1:4] / mass
    return 2.0 * float(np.sqrt(np.sum(std[1:4] ** 2 + (com * std[0]) ** 2))) / mass


def model_doubt(estimate, config: GateConfig) -> tuple[str, str] | None:
    """``(reason, detail)`` if the model's own figures say its estimate (an
    :class:`iem.types.PayloadEstimate`) is not good enough to write, else None. It fails
    closed: what it needs and the estimate does not report holds the write back.

    - ``unreported``: the estimate is not a :class:`iem.types.PayloadEstimate`, or it does
      not report its standard deviations (``std``), its data's verdict (``nis``) or its
      out-of-distribution verdict (``ood``): None for any of them. Unless the cell allows
      writing without them (``allow_without_uncertainty``; the paper's IEM needs it): then
      what is reported is still checked;
    - ``out_of_distribution``: ``ood``: the IEM's learner met an input far beyond its bag's
      training inputs (:meth:`iem.ensemble.IncrementalEnsemble.ood_score`);
    - ``unverified``: the estimate started from a payload file and the model has not yet
      tested it against enough live data;
    - ``uncertain``: ``2 * std[0]`` (the 2-sigma band on the mass, kg) is wider than
      ``max_mass_2sigma_kg``, or the 2-sigma radius of the CoM is wider than
      ``max_com_2sigma_m``, or either is not a number (no band known). The CoM's standard
      deviations are those of ``r = (m r) / m`` to first order, ``sqrt(std[1:4]**2 +
      (r * std[0])**2) / m`` (the estimate carries standard deviations, not their
      correlations); the radius is their norm;
    - ``data_disagree``: ``nis`` (the mean normalised innovation squared per degree of
      freedom over the model's recent equations, about 1 when the data agree with the
      model) exceeds ``max_nis``; a NaN ``nis`` (no equation tested yet) does not hold a
      write back.
    """
    from iem.types import PayloadEstimate

    if not isinstance(estimate, PayloadEstimate):
        if config.allow_without_uncertainty and estimate is None:
            return None
        return ("unreported", f"the model gave {type(estimate).__name__}, not a "
                              "PayloadEstimate: nothing says how good it is")
    missing = [name for name in ("std", "nis", "ood") if getattr(estimate, name) is None]
    if missing and not config.allow_without_uncertainty:
        return ("unreported", f"the model does not report {', '.join(missing)}; set [gate] "
                              "allow_without_uncertainty = true to write without them")
    if estimate.ood:
        extra = estimate.extra or {}
        why = (f"the learner's input lies {extra.get('ood_score', 0):.3g} standard deviations "
               "beyond what its bag was trained on")
        if "velocity_score" in extra:
            why += (f" (its joint velocities score {extra['velocity_score']:.3g} against the "
                    "bag's training velocities)")
        return ("out_of_distribution", why)
    if estimate.unverified:
        return ("unverified", "the estimate starts from a payload file and has not yet been "
                              "tested against enough live data")
    if estimate.std is not None:
        wide = _too_uncertain(estimate.phi, estimate.std, config)
        if wide is not None:
            return ("uncertain", wide)
    nis = estimate.nis
    if nis is not None and not math.isnan(nis) and not nis <= config.max_nis:
        return ("data_disagree", f"normalised innovation squared {nis:.3g} per degree of "
                                 f"freedom > {config.max_nis:g}: the data disagree with the model")
    return None


def _too_uncertain(phi, std, config: GateConfig) -> str | None:
    """Why the 2-sigma band on the mass or the 2-sigma radius of the CoM is wider than the
    gate's limit (or not a number), or None if neither is."""
    band = 2.0 * float(np.asarray(std, dtype=float).reshape(-1)[0])
    if not band <= config.max_mass_2sigma_kg:
        return f"2-sigma band on the mass {band:.4g} kg > {config.max_mass_2sigma_kg:g} kg"
    radius = com_2sigma(phi, std)
    if not radius <= config.max_com_2sigma_m:
        return (f"2-sigma radius of the CoM {radius * 1e3:.3g} mm > "
                f"{config.max_com_2sigma_m * 1e3:g} mm")
    return None
