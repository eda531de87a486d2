"""The safety gate's checks of one estimate on its own: its contract (types, shapes, signs,
one uncertainty), what it is (finite, a possible rigid body of that mass within the arm's
reach, within the robot's rating with the end effector at the band's worst, its CoM within
the radius, within the wire's ranges) and what the model says of it (its verdicts, the
agreement of the data, the inertia's band). The gate (:mod:`deploy.writeback.gate`) adds
what depends on time and on the controller: the age, the load in force, commands, stability,
whether a write helps, and rate. Every check returns a reason and its detail, never raises,
whatever it is given.

A raw estimate is read once (:func:`read`): its fields checked and turned into a
:class:`Reading` of plain numbers, on which every later rule works.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from iem.payload import Payload
from iem.physics.consistency import project
from iem.types import PayloadEstimate

if TYPE_CHECKING:
    from .settings import GateConfig

WireCheck = Callable[[Payload], "str | None"]
"""A link's range check of a load: why its wire format cannot carry it, or None."""

_PRIOR_EPS = 1e-6
"""A prior made a possible body is at least this second moment per kilogram in every direction
(m²: a millimetre's), not just inside the boundary of the set."""

COV_AGREES = 1e-6
"""The covariance's diagonal must agree with the standard deviations this closely (relative,
on the standard deviation)."""
COV_SYMMETRIC = 1e-9
"""The covariance's asymmetry and its most negative eigenvalue may be at most this share of
its largest entry (rounding)."""


@dataclass(frozen=True)
class Reading:
    """A raw estimate as the gate reads it, its contract checked (:func:`read`).

    Attributes:
        t: the estimate's time, s (finite).
        std: its standard deviations (10, >= 0, inf: nothing known), or None.
        sigma: the larger of ``std`` and the covariance's diagonal's square root per
            parameter: the one uncertainty every rule uses (None: neither reported).
        cov: the covariance (10x10, symmetric, positive semidefinite) with its diagonal
            raised to ``sigma ** 2``; None without one, or where a parameter's ``sigma`` is
            infinite (then the band alone bounds a write).
        nis, ood, unverified, determined: as reported (``nis`` a float or None).
        prior: the prior's parameters (10 finite numbers) or None.
        extra: the diagnostics (a dict; empty if the estimate's was not one).
    """

    t: float
    std: np.ndarray | None
    sigma: np.ndarray | None
    cov: np.ndarray | None
    nis: float | None
    ood: bool | None
    unverified: bool | None
    determined: tuple | None
    prior: np.ndarray | None
    extra: dict

    def band(self) -> np.ndarray:
        """The 2-sigma band per parameter (zeros without an uncertainty)."""
        return np.zeros(10) if self.sigma is None else 2.0 * self.sigma


def _real(value) -> bool:
    """A real number (not a bool, a string or an array)."""
    return isinstance(value, int | float | np.integer | np.floating) and not isinstance(
        value, bool | np.bool_)


def _array(value, shape: tuple) -> np.ndarray | None:
    """``value`` as a float array of ``shape``, or None if it is not numbers of that shape."""
    try:
        out = np.array(value, dtype=float)
    except (TypeError, ValueError, OverflowError):
        return None
    return out if out.shape == shape else None


def read(estimate) -> tuple[Reading | None, tuple[str, str] | None]:
    """``(reading, None)`` of a raw estimate that keeps its contract, ``(None, (reason,
    detail))`` of one that breaks it (``malformed``), ``(None, None)`` of one that is not a
    :class:`iem.types.PayloadEstimate` at all (left to :func:`model_doubt`: ``unreported``).

    The contract: ``phi`` 10 numbers; ``std`` None or 10 numbers ``>= 0`` (inf allowed);
    ``cov`` None or a finite symmetric positive-semidefinite 10x10 matrix whose diagonal
    agrees with ``std`` (relative :data:`COV_AGREES`) where ``std`` is finite; ``nis`` None or
    a number ``>= 0`` or NaN; ``t`` a finite number; ``ood`` and ``unverified`` None or
    bools; ``determined`` None or a tuple of group names; ``prior`` None or 10 finite
    numbers."""
    if not isinstance(estimate, PayloadEstimate):
        return None, None
    e = estimate
    if not _real(e.t) or not math.isfinite(e.t):
        return None, ("malformed", f"the estimate's time {_text(e.t)} is not a finite number")
    if _array(e.phi, (10,)) is None:
        return None, ("malformed", f"phi is {_shape(e.phi)}, valid is 10 numbers")
    std = None
    if e.std is not None:
        std = _array(e.std, (10,))
        if std is None:
            return None, ("malformed", f"std is {_shape(e.std)}, valid is 10 numbers or None")
        if np.isnan(std).any() or (std < 0).any():
            return None, ("malformed", f"std has a negative or NaN entry ({_worst(std)}); "
                                       "valid is >= 0")
    cov = None
    if e.cov is not None:
        cov = _array(e.cov, (10, 10))
        if cov is None:
            return None, ("malformed", f"cov is {_shape(e.cov)}, valid is a 10x10 covariance "
                                       "or None")
    why, sigma, cov = _UNCERTAINTY(std, cov)
    if why:
        return None, ("malformed", why)
    nis = e.nis
    if nis is not None:
        if not _real(nis):
            return None, ("malformed", f"nis is {_text(nis)}; valid is a number >= 0, NaN or "
                                       "None")
        nis = float(nis)
        if nis < 0 or math.isinf(nis):
            return None, ("malformed", f"nis {nis:.4g} is negative or infinite; valid is >= 0 "
                                       "or NaN (no verdict yet)")
    for name in ("ood", "unverified"):
        value = getattr(e, name)
        if not (value is None or isinstance(value, bool | np.bool_)):
            return None, ("malformed", f"{name} is {type(value).__name__}; valid is True, "
                                       "False or None")
    determined = e.determined
    if determined is not None and not (isinstance(determined, tuple)
                                       and all(isinstance(g, str) for g in determined)):
        return None, ("malformed", "determined is not None nor a tuple of group names")
    prior = getattr(e, "prior", None)
    if prior is not None:
        prior = _array(prior, (10,))
        if prior is None or not np.isfinite(prior).all():
            return None, ("malformed", "prior is not 10 finite numbers; valid is those or None")
    return Reading(float(e.t), std, sigma, cov, nis, None if e.ood is None else bool(e.ood),
                   None if e.unverified is None else bool(e.unverified), determined, prior,
                   e.extra if isinstance(e.extra, dict) else {}), None


class _LastUncertainty:
    """``(why, sigma, cov)`` of a checked ``std`` and ``cov`` (either None): why ``cov`` is
    no covariance that agrees with ``std`` (:func:`_cov_error`; then no sigma, no cov), else
    :func:`_one_uncertainty`'s pair (read-only). A model's estimates between two refreshes of
    its posterior report the same ``std`` and ``cov``: the pair last checked is remembered
    (copies, compared by value), so each is checked once, and the answer is the one the
    checks give."""

    def __init__(self) -> None:
        self._last = None  # (std, cov, answer)

    def __call__(self, std: np.ndarray | None, cov: np.ndarray | None) -> tuple:
        last = self._last
        if last is not None and _same(std, last[0]) and _same(cov, last[1]):
            return last[2]
        why = None if cov is None else _cov_error(cov, std)
        if why:
            answer = (why, None, None)
        else:
            sigma, raised = _one_uncertainty(std, cov)
            answer = (None, _frozen(sigma), _frozen(raised))
        self._last = (_frozen(std), _frozen(cov), answer)
        return answer


def _same(a: np.ndarray | None, b: np.ndarray | None) -> bool:
    """Both None, or the same values (NaN never the same)."""
    if a is None or b is None:
        return a is b
    return a.shape == b.shape and bool((a == b).all())


def _frozen(a: np.ndarray | None) -> np.ndarray | None:
    """A read-only copy of ``a`` (None: None)."""
    if a is None:
        return None
    a = np.array(a, dtype=float)
    a.flags.writeable = False
    return a


_UNCERTAINTY = _LastUncertainty()


def _cov_error(cov: np.ndarray, std: np.ndarray | None) -> str | None:
    """Why ``cov`` is not a covariance that agrees with ``std``, or None."""
    if not np.isfinite(cov).all():
        return "cov has NaN or infinite entries; valid is a finite 10x10 covariance"
    scale = float(np.abs(cov).max())
    asym = float(np.abs(cov - cov.T).max())
    if asym > COV_SYMMETRIC * scale:
        return f"cov is not symmetric (|C - C^T| up to {asym:.3g}); valid is a covariance"
    lowest = float(np.linalg.eigvalsh(0.5 * (cov + cov.T))[0])
    if lowest < -COV_SYMMETRIC * scale:
        return (f"cov is not positive semidefinite (eigenvalue {lowest:.3g}); valid is a "
                "covariance")
    if std is not None:
        root = np.sqrt(np.maximum(np.diag(cov), 0.0))
        finite = np.isfinite(std)
        off = np.abs(root - std) > COV_AGREES * np.maximum(root, std)
        bad = np.flatnonzero(finite & off)
        if bad.size:
            i = int(bad[0])
            return (f"cov's diagonal disagrees with std: sqrt(cov[{i},{i}]) = {root[i]:.6g}, "
                    f"std[{i}] = {std[i]:.6g}; valid: the same within a relative "
                    f"{COV_AGREES:g}")
    return None


def _one_uncertainty(std, cov) -> tuple[np.ndarray | None, np.ndarray | None]:
    """``(sigma, cov)``: the larger of what ``std`` and ``cov`` say per parameter, and
    ``cov`` with its diagonal raised to it (None where a sigma is infinite)."""
    if cov is None:
        return std, None
    root = np.sqrt(np.maximum(np.diag(cov), 0.0))
    sigma = root if std is None else np.maximum(std, root)
    if not np.isfinite(sigma).all():
        return sigma, None
    raised = 0.5 * (cov + cov.T)
    raised[np.diag_indices(10)] = np.maximum(np.diag(raised), sigma ** 2)
    return sigma, raised


def check_estimate(phi: np.ndarray, config: GateConfig, wire_check: WireCheck | None = None,
                   sigma: np.ndarray | None = None, cov: np.ndarray | None = None
                   ) -> tuple[str, str]:
    """``(reason, detail)`` of the estimate ``phi`` (paper order) with standard deviations
    ``sigma`` and covariance ``cov`` (None: the values alone, as of a file; the covariance
    unknown): ``reason`` is ``""`` when it may be
    written as far as its values go, else ``not_finite``, ``inconsistent`` (not a possible
    rigid body: a mass not > 0, an inertia about the CoM that is not positive definite or
    breaks the triangle inequality, or more than a body of that mass within the arm's reach
    can have), ``over_rated`` (the payload and the declared end effector together beyond
    the arm's rated payload), ``com_too_far``, ``out_of_wire_range`` or ``malformed`` (not
    10 values); ``uncertain`` while the mass's band reaches zero (the gate writes the empty
    load once it has for its stability window: no CoM or inertia is judged of such a mass).
    The rating and the inertia's bound are judged at the 2-sigma band's worst; the CoM's
    radius at the value written (its band is the write rule's to judge, by the torque it can
    cost: :mod:`deploy.writeback.write_rule`)."""
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
    band = np.zeros(10) if sigma is None else 2.0 * np.where(np.isfinite(sigma), sigma, 0.0)
    worst_mass = payload.mass + band[0]
    if worst_mass + c.end_effector_mass_kg > c.rated_mass_kg:
        return "over_rated", (
            f"mass {payload.mass:.3f}{_pm(band[0])} kg + end effector "
            f"{c.end_effector_mass_kg:.3f} kg > rated {c.rated_mass_kg:g} kg")
    if band[0] > 0.0 and not payload.mass - band[0] > 0.0:
        return "uncertain", (f"mass {payload.mass:.3f}{_pm(band[0])} kg: not told from the "
                             "empty load yet (no CoM or inertia is judged of a mass that may "
                             "be none)")
    radius = float(np.linalg.norm(payload.com))
    if radius > c.max_com_radius_m:
        return "com_too_far", (f"CoM {radius:.3f}{_pm(_com_band(phi, band, cov))} m from the "
                               f"flange > {c.max_com_radius_m:g} m")
    bound = inertia_bound(phi, band, c.reach_m)
    if bound is not None:
        return "inconsistent", bound
    if wire_check is not None:
        why = wire_check(payload)
        if why:
            return "out_of_wire_range", f"the link's wire format cannot carry it: {why}"
    return "", ""


def _pm(band: float) -> str:
    return f" (+{band:.3f} at 2 sigma)" if band > 0 else ""


def _com_band(phi: np.ndarray, band: np.ndarray, cov: np.ndarray | None = None) -> float:
    """The 2-sigma band of the CoM's distance from the flange, m, to first order in the
    mass and the first moment (``c = h / m``: ``J = [-c / m, I / m]``, the CoM's covariance
    ``J C J^T`` with ``C`` the estimate's covariance of ``m`` and ``h``, or their variances
    from ``band`` without one): twice the root of its largest eigenvalue, the band's edge
    in any direction. Infinite when the mass's band reaches zero (the CoM of a mass that may
    be none is not determined)."""
    m = float(phi[0])
    if not band[:4].any():
        return 0.0
    if not m - band[0] > 0.0:
        return math.inf
    c = phi[1:4] / m
    jac = np.hstack([-c[:, None] / m, np.eye(3) / m])
    c4 = np.diag((band[:4] / 2.0) ** 2) if cov is None else cov[:4, :4]
    cov_c = jac @ c4 @ jac.T
    return 2.0 * math.sqrt(max(float(np.linalg.eigvalsh(0.5 * (cov_c + cov_c.T))[-1]), 0.0))


def inertia_bound(phi: np.ndarray, band: np.ndarray, reach_m: float) -> str | None:
    """Why the inertia about the CoM of ``phi`` is more than a body of its mass within
    ``reach_m`` of its CoM can have, at the 2-sigma band's worst, or None: every point of
    such a body is within the reach, so ``trace(I_c) / 2 = sum m_i |r_i - c|^2 <= m
    reach^2``."""
    m = float(phi[0])
    inertia_c = Payload.from_phi(phi).inertia_matrix
    half_trace = 0.5 * float(np.trace(inertia_c)) + 0.5 * float(band[[4, 7, 9]].sum())
    low = max(m - band[0], 0.0)
    limit = low * reach_m ** 2
    if half_trace <= limit:
        return None
    return (f"inertia about the CoM (half its trace {half_trace:.4g} kg·m² at 2 sigma) beyond "
            f"what {low:.3f} kg within the arm's reach {reach_m:g} m can have "
            f"({limit:.4g} kg·m²)")


def model_doubt(estimate, config: GateConfig, reading: Reading | None = None
                ) -> tuple[str, str] | None:
    """``(reason, detail)`` if the model's own figures say its ``estimate`` is not fit to
    write, else None (``reading``: the estimate as :func:`read` gives it, if read already;
    an estimate that breaks its contract is ``malformed``). It fails closed: what it needs
    and the estimate does not report holds the write back.

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
      determine is written as the prior has it, and the write says so; without a prior the
      estimate gives, it is not written);
    - ``data_disagree``: ``nis`` (the mean normalised innovation squared per degree of
      freedom over the model's recent equations, about 1 when the data agree with the
      model) exceeds ``max_nis``; a NaN ``nis`` (no equation tested yet) does not hold a
      write back, but the estimate is then its prior's, which the gate's comparison with
      the load in force judges by its band.
    """
    if reading is None:
        reading, broken = read(estimate)
        if broken:
            return broken
    if reading is None:
        if config.allow_without_uncertainty and estimate is None:
            return None
        return ("unreported", f"the model gave {type(estimate).__name__}, not a "
                              "PayloadEstimate: nothing says how good it is")
    r = reading
    missing = [name for name, value in (("std", r.std), ("nis", r.nis), ("ood", r.ood))
               if value is None]
    if missing and not config.allow_without_uncertainty:
        return ("unreported", f"the model does not report {', '.join(missing)}; set [gate] "
                              "allow_without_uncertainty = true to write without them")
    if r.ood:
        why = (f"the learner's input lies {_score(r.extra.get('ood_score'))} standard "
               "deviations beyond what its bag was trained on")
        if "velocity_score" in r.extra:
            why += (f" (its joint velocities score {_score(r.extra['velocity_score'])} against "
                    "the bag's training velocities)")
        return ("out_of_distribution", why)
    if r.unverified:
        return ("unverified", "the estimate starts from a payload file or a restored state "
                              "and has not yet been tested against enough live data")
    determined = r.determined
    if determined is not None and not {"mass", "com"} <= set(determined):
        missing = " and ".join(g for g in ("mass", "com") if g not in determined)
        settle = r.extra.get("settle")  # what motion would (the model's words)
        settle = settle if isinstance(settle, str) else ""
        return ("uncertain", f"the data do not determine the {missing} yet: it is the "
                             "prior's guess, not a measurement"
                             + (f"; {settle}" if settle else ""))
    if determined is not None and "inertia" not in determined and r.prior is None:
        return ("uncertain", "the data do not determine the inertia and the model reports no "
                             "prior to write in its place")
    if r.sigma is not None:
        wide = _band_unusable(r.sigma, r, config)
        if wide is not None:
            return ("uncertain", wide)
    nis = r.nis
    if nis is not None and not math.isnan(nis) and not nis <= config.max_nis:
        return ("data_disagree", f"normalised innovation squared {nis:.3g} per degree of "
                                 f"freedom > {config.max_nis:g}: the data disagree with the model")
    return None


def _band_unusable(sigma: np.ndarray, reading: Reading, config: GateConfig) -> str | None:
    """Why the estimate's band cannot bound a write, or None."""
    if not np.isfinite(sigma[:4]).all():
        return "no band on the mass or the first moment (an infinite standard deviation)"
    determined = reading.determined
    if determined is not None and "inertia" not in determined:
        return None  # written as the prior has it, said so in the send's detail
    band = 2.0 * float(sigma[4:].max())
    if not band <= config.max_inertia_2sigma_kgm2:
        return (f"2-sigma band on the inertia {band:.4g} kg·m² > "
                f"{config.max_inertia_2sigma_kgm2:g} kg·m²")
    return None


def with_prior_inertia(phi: np.ndarray, reading: Reading) -> np.ndarray:
    """``phi`` with the inertia about its CoM taken from the estimate's prior where the data
    do not determine the inertia (as the write says); ``phi`` itself otherwise, or when the
    prior has no body to take an inertia from (then :func:`check_estimate` judges ``phi``).
    A prior that is not a possible rigid body (a learnt prior need not be: its inertia about
    its own CoM may break the triangle inequality) gives the inertia of the nearest one
    (:func:`iem.physics.consistency.project`, unweighted)."""
    determined, prior = reading.determined, reading.prior
    if determined is None or "inertia" in determined or prior is None:
        return phi
    if not (phi[0] > 0.0 and prior[0] > 0.0 and np.isfinite(prior).all()):
        return phi
    body = Payload.from_phi(prior)
    if body.consistency_violations():
        body = Payload.from_phi(project(prior, eps=_PRIOR_EPS * float(prior[0])))
    inertia = body.inertia
    mass, com = float(phi[0]), tuple(float(v) for v in phi[1:4] / phi[0])
    return Payload("estimate", mass, com, inertia).to_phi()


def mass_band(mass: float, mass_std) -> tuple[float, float]:
    """The mass's 2-sigma band ``(low, high)``, kg, of a mass and its standard deviation
    (None: no band, the mass alone; NaN or inf: nothing known, the whole line)."""
    m = float(mass)
    s = 0.0 if mass_std is None else float(mass_std)
    if math.isnan(s):
        s = math.inf
    return m - 2.0 * s, m + 2.0 * s


def excludes_zero(mass: float, mass_std) -> bool:
    """Whether the mass's 2-sigma band excludes a zero mass (lies above it): the estimate
    is a body whose CoM and inertia mean something; otherwise it is not told from the empty
    load (the status line shows no CoM then, and the gate judges the empty load)."""
    return mass_band(mass, mass_std)[0] > 0.0


def _worst(std: np.ndarray) -> str:
    bad = np.flatnonzero(np.isnan(std) | (std < 0))
    return ", ".join(f"std[{i}] = {std[i]:.4g}" for i in bad[:3])


def _score(value) -> str:
    """A score from ``extra`` in words: a number to 3 digits, else what it is."""
    if _real(value):
        return f"{float(value):.3g}"
    return "an unknown number of" if value is None else f"a {type(value).__name__} of"


def _text(value) -> str:
    """A value for an error message, never longer than 40 characters."""
    try:
        text = repr(value)
    except Exception:  # a value whose repr fails: name its type
        text = f"a {type(value).__name__}"
    return text if len(text) <= 40 else text[:37] + "..."


def _shape(value) -> str:
    try:
        return f"of shape {np.shape(value)}"
    except Exception:
        return f"a {type(value).__name__}"

