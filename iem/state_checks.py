"""The numbers of a model file's state checked before a model is rebuilt from them.

A model file's state is plain data (:mod:`iem.persistence`): maps, lists, numbers, strings.
Before ``from_state`` sees a state, :func:`check_state` walks it and checks every number
against the rule of its key (:data:`RULES`, matched on the end of the key's path, list
positions left out: ``ensemble.learners.a`` is every learner's ``a``):

- every number is finite (a NaN or an infinity anywhere is refused);
- a count (equations, estimates, samples, bags) is an integer from 0 to :data:`MAX_COUNT`;
- a hyper-parameter that sizes a buffer or a loop (a reservoir, epochs, iterations, bags) is
  an integer within the range its rule gives, so that no file makes the model allocate or
  loop without end;
- a rate, a standard deviation, a learning rate or a threshold is a number within its range
  (most of them > 0);
- a covariance, a precision or an information matrix, and the sums of outer products the
  models keep, is square, symmetric and positive semidefinite (to a relative 1e-9).

A key whose rule is "any finite number" (:data:`FREE`: a network's weights, a mean) is
checked for finiteness alone. A number whose key has no rule is checked for finiteness
too; a test (``tests/iem/test_model_file_bounds.py``) holds the keys of every kind's state to
a rule.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator

import numpy as np

__all__ = ["MAX_COUNT", "RULES", "StateError", "check_state", "dotted", "numbers_in", "rule_of"]

MAX_COUNT = 10**11
"""Largest count a state may hold: 30 years of 100 block points a second."""


class StateError(ValueError):
    """A number of a state breaks its rule (the message names the key and the rule)."""


Rule = Callable[[str, object], None]


def _numbers(value) -> np.ndarray:
    """``value`` as a float array (a ragged list: its numbers, flat)."""
    try:
        return np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        pass
    try:
        return np.fromiter((float(v) for v in _flat(value)), dtype=float)
    except (TypeError, ValueError):
        raise StateError("is not a number or a list of numbers") from None


def _finite(key: str, value) -> np.ndarray:
    a = _numbers(value)
    bad = ~np.isfinite(a)
    if bad.any():
        raise StateError(f"holds {np.count_nonzero(bad)} value(s) that are not finite numbers "
                         f"(None, NaN or infinity; the first: {float(a[bad].flat[0])}); every "
                         "number of a model must be one")
    return a


def _integers(key, value, lo: float, hi: float, what: str):
    a = _finite(key, value)
    ints = np.all([isinstance(v, int) and not isinstance(v, bool)
                   for v in _flat(value)]) if a.size else True
    if not ints:
        raise StateError(f"holds a value that is not an integer; valid: {what}, integers "
                         f"from {lo:g} to {hi:g}")
    if a.size and (a.min() < lo or a.max() > hi):
        v = a.min() if a.min() < lo else a.max()
        raise StateError(f"holds {v:g}; valid: {what}, integers from {lo:g} to {hi:g}")


def _flat(value) -> Iterator:
    if isinstance(value, list | tuple):
        for v in value:
            yield from _flat(v)
    else:
        yield value


def count(key, value) -> None:
    """A count: integers from 0 to :data:`MAX_COUNT`."""
    _integers(key, value, 0, MAX_COUNT, "a count")


def index(key, value) -> None:
    """An index, or -1 for none."""
    _integers(key, value, -1, MAX_COUNT, "an index (-1: none)")


def size(lo: int, hi: int, what: str) -> Rule:
    """A hyper-parameter that sizes a buffer or a loop: integers from ``lo`` to ``hi``."""
    def rule(key, value) -> None:
        _integers(key, value, lo, hi, what)
    rule.__doc__ = f"{what}: integers from {lo} to {hi}"
    return rule


def within(lo: float, hi: float, what: str, open_low: bool = False) -> Rule:
    """Numbers in ``[lo, hi]`` (``(lo, hi]`` if ``open_low``)."""
    def rule(key, value) -> None:
        a = _finite(key, value)
        if not a.size:
            return
        low, high = float(a.min()), float(a.max())
        if low < lo or (open_low and low == lo) or high > hi:
            bad = high if high > hi else low
            raise StateError(f"holds {bad:g}; valid: {what}, numbers in "
                             f"{'(' if open_low else '['}{lo:g}, {hi:g}]")
    return rule


def free(key, value) -> None:
    """Any finite numbers (weights, means, filter states)."""
    _finite(key, value)


def psd(key, value) -> None:
    """Square, symmetric, positive semidefinite matrices (or a list of them)."""
    a = _finite(key, value)
    if a.size == 0:
        return
    if a.ndim < 2 or a.shape[-1] != a.shape[-2]:
        raise StateError(f"has the shape {a.shape}; valid: a square matrix (a covariance, "
                         "precision or sum of outer products)")
    for m in a.reshape(-1, a.shape[-1], a.shape[-1]):
        scale = float(np.abs(m).max()) if m.size else 0.0
        if scale == 0.0:
            continue
        if np.abs(m - m.T).max() > 1e-9 * scale:
            raise StateError("is not symmetric; valid: a symmetric positive semidefinite "
                             "matrix (a covariance, precision or sum of outer products)")
        low = float(np.linalg.eigvalsh(0.5 * (m + m.T)).min())
        if low < -1e-9 * scale:
            raise StateError(f"has the eigenvalue {low:.3g}; valid: a positive semidefinite "
                             "matrix (a covariance, precision or sum of outer products)")


def initial(key, value) -> None:
    """A known payload started from: ``[phi (10), its covariance (10 x 10)]``."""
    if not (isinstance(value, list) and len(value) == 2):
        raise StateError("valid: [phi (10 numbers), its covariance (10 x 10)]")
    free(key, value[0])
    psd(key, value[1])


FREE = free
POSITIVE = within(0.0, 1e12, "a number > 0", open_low=True)
NONNEGATIVE = within(0.0, 1e12, "a number >= 0")

RULES: dict[str, Rule] = {
    # -- counts and indices -----------------------------------------------------------------
    **{k: count for k in (
        "m", "n", "count", "counts", "calib_n", "calib_bins.n", "bag_counts", "holdoff",
        "changes", "since_refresh", "retired", "promoted", "equations", "gen", "calib_gen",
        "updates", "seen", "shapes", "n_samples", "on_probation", "detector.n",
        "post.equations")},
    "open": index,
    "feature": index, "left": index, "right": index,
    # -- seeds and generator states (numpy checks the rest of a generator's state) -----------
    "seed": size(0, 2**64 - 1, "a seed"),
    "rng.has_uint32": size(0, 1, "a flag"),
    "rng.uinteger": size(0, 2**32 - 1, "a 32-bit integer"),
    "rng.state.state": size(0, 2**128 - 1, "a generator state"),
    "rng.state.inc": size(0, 2**128 - 1, "a generator state"),
    # -- hyper-parameters that size a buffer or a loop ---------------------------------------
    "iters": size(0, 10_000, "iterations"),
    "warmup_iters": size(0, 1_000_000, "iterations"),
    "fit_epochs": size(0, 10_000, "epochs"),
    "close_epochs": size(0, 10_000, "epochs"),
    "fit_stride": size(1, 1_000_000, "a stride"),
    "reservoir": size(0, 100_000, "samples kept"),
    "capacity": size(0, 100_000, "samples kept"),
    "coverage_draws": size(0, 1_000, "draws"),
    "budget_bags": size(1, 1_000_000, "bags"),
    "probation_bags": size(0, 1_000_000, "bags"),
    "n_networks": size(0, 10_000, "networks"),
    "n_trees": size(0, 10_000, "trees"),
    "max_depth": size(1, 64, "a tree depth"),
    "min_samples_leaf": size(1, 1_000_000, "samples"),
    "max_features": size(1, 1_000, "features"),
    "n_features": size(1, 1_000, "features"),
    "n_outputs": size(1, 1_000, "outputs"),
    "refresh_every": size(1, 1_000_000, "points"),
    "project_budget": size(0, 1_000_000, "projections"),
    "point_frames": size(1, 1_000, "frames per block point"),
    "update_every": size(1, 1_000, "points"),
    "decimate": size(0, 1_000_000, "points"),
    # -- rates, spreads, learning rates and thresholds -------------------------------------
    "rate_hz": within(0.0, 100_000.0, "a rate in Hz", open_low=True),
    "cutoff_hz": within(0.0, 100_000.0, "a frequency in Hz", open_low=True),
    "sigma_tau": within(0.0, 1_000.0, "a torque spread in N·m", open_low=True),
    "sigma_dq": within(0.0, 1_000.0, "a velocity spread in rad/s", open_low=True),
    "input_noise": within(0.0, 1_000.0, "spreads of the inputs"),
    "prior_std": within(0.0, 1e6, "spreads of the prior", open_low=True),
    "scale": within(0.0, 1e12, "input scales", open_low=True),
    "lr": within(0.0, 1e3, "a learning rate", open_low=True),
    "fit_lr": within(0.0, 1e3, "a learning rate", open_low=True),
    "delta": within(0.0, 1e3, "a joint-space threshold in rad", open_low=True),
    "rho": within(0.0, 1e3, "a Cartesian threshold in m", open_low=True),
    "eps": within(0.0, 1.0, "a regularisation", open_low=True),
    "prior_scale": POSITIVE,
    "drift": NONNEGATIVE,
    "params.threshold": POSITIVE,
    "ood_threshold": POSITIVE,
    "velocity_threshold": POSITIVE,
    "ood_hold_s": within(0.0, 86_400.0, "a time in s"),
    "holdoff_s": within(-1.0, 86_400.0, "a time in s (-1: the default)"),
    "center_rate": within(0.0, 1.0, "a rate per point"),
    "post.inflation": within(0.0, 1e12, "a factor", open_low=True),
    "detector.g": NONNEGATIVE,
    "detector.last": NONNEGATIVE,
    "detector.level": POSITIVE,
    "detector.level_model": POSITIVE,
    "calib_bins.sq": NONNEGATIVE,
    # the torque noise checks itself (iem.physics.torque_noise.TorqueNoise)
    "torque_noise.std": NONNEGATIVE, "torque_noise.weight": NONNEGATIVE,
    "torque_noise.offset_std": NONNEGATIVE, "torque_noise.bias_std": NONNEGATIVE,
    "torque_noise.gain_std": NONNEGATIVE,
    # the open bag's statistics of the expected learner (iem.ensemble.expected)
    "kept.points": count,
    # the posterior before an alarm (iem.physics.candidate)
    "candidate.decide_n": count, "candidate.compared": count, "candidate.samples": count,
    "candidate.evidence": FREE,
    "kept.span": POSITIVE,
    "kept.noise": NONNEGATIVE,
    # -- covariances, precisions, information and sums of outer products -------------------
    **{k: psd for k in ("post.cov", "post.precision", "P", "calib", "noise0", "sum_c_base",
                        "info", "sum_outer", "dq_precision", "kept.gram")},
    # -- free: weights, means, filter states, offsets (finite) -----------------------------
    **{k: free for k in (
        "means", "lo", "hi", "center", "a", "b", "out", "eta", "sum_phi", "post.mean", "phi",
        "filter", "input", "output", "previous", "last", "trees.threshold", "trees.value",
        "offsets", "gains", "block", "kept.prior", "kept.cross",
        "arm")},  # (arm: an equation window's sums of the arm's sensitivity)
    "initial": initial,
}
"""The rule of each key (matched on the end of its path; the longest match wins)."""


def rule_of(path: tuple[str, ...]) -> Rule | None:
    """The rule of the key at ``path`` (the longest match of its end in :data:`RULES`), or
    None."""
    for i in range(len(path)):
        rule = RULES.get(".".join(path[i:]))
        if rule is not None:
            return rule
    return None


def numbers_in(state, path: tuple[str, ...] = ()) -> Iterator[tuple[tuple[str, ...], object]]:
    """``(path, value)`` of every value of ``state`` that holds numbers: a number, or a list
    of numbers (nested); maps are walked, lists of maps walked item by item."""
    if isinstance(state, dict):
        for key, value in state.items():
            yield from numbers_in(value, (*path, str(key)))
    elif isinstance(state, list) and state and any(isinstance(v, dict) for v in state):
        for v in state:
            yield from numbers_in(v, path)
    elif isinstance(state, list):
        if any(_is_number(v) for v in _flat(state)):
            yield path, state
    elif _is_number(state):
        yield path, state


def _is_number(v) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def dotted(path: tuple[str, ...]) -> str:
    """``path`` as a message names it: ``ensemble.router.counts`` (an odd key as ``['a b']``)."""
    out = ""
    for key in path:
        out += f".{key}" if key.isidentifier() else f"[{key!r}]"
    return out.lstrip(".")


def check_state(state: dict) -> None:
    """Check every number of ``state`` by the rule of its key (module docstring).

    Raises:
        StateError: naming the key (its path) and what is valid.
    """
    for path, value in numbers_in(state):
        rule = rule_of(path)
        if isinstance(value, list) and any(isinstance(v, str | bytes) for v in _flat(value)):
            continue  # a list that is not all numbers (bytes of samples, names)
        try:
            (rule or free)(".".join(path), value)
        except StateError as exc:
            raise StateError(f"{dotted(path)} {exc}") from None
