"""Compiled kernels of the per-sample numerics (numba): an opt-in, ``IEM_KERNELS=numba``.

A cycle at 1 kHz is a burst of a hundred small interpreter and NumPy calls that starts cold
every millisecond: the same step costs about three times its back-to-back cost when it is
fed at 1 kHz (README, the hot path's seventh and eighth passes). Where the work is a few
dozen multiply-adds on a handful of small arrays, one compiled call does it in a fraction
of what the NumPy calls' dispatch alone costs, back to back and cold alike.

The price is memory: numba, scipy.linalg and LLVM add about 120 MB of resident memory,
which takes ``iem bench longrun``'s 60-minute run past its 300 MB target. So the NumPy code
beside each caller (``iem.router``, ``iem.learner``, ``iem.prior_summary``,
``iem.filters``, ``iem.smoothing``) is the default and the description; with the
environment variable ``IEM_KERNELS=numba`` (numba installed: ``pip install '.[fast]'``)
:data:`active` is true and the callers call these kernels instead. The tests
(``tests/iem/test_kernels.py``) hold each kernel to its NumPy: to the bit where the
arithmetic is the same (the routing, the SGD, whose products are the same BLAS calls, the
mass-bin table), within 1e-12 elsewhere.

The kernels are written here as plain Python over arrays; :func:`load` compiles them with
numba (explicit signatures, so no call waits for type inference) or loads them from
numba's cache beside this module (or ``NUMBA_CACHE_DIR``; a read-only install caches in the
user's cache directory). Importing this module imports nothing but NumPy (the ``iem``
core's rule); :class:`iem.online.OnlineIdentifier` calls :func:`load` when it is made, if
the kernels are on, so no cycle waits for a compiler.

Every array a kernel takes is float64 (int64 for counts), of any layout, read-only where
the kernel only reads it; kernels do not check shapes (their callers do), and allocate
nothing but what they return.
"""

from __future__ import annotations

import logging
import os
import threading

import numpy as np

from .errors import InvalidInputError

log = logging.getLogger(__name__)

ENV = "IEM_KERNELS"
"""The environment variable that chooses the per-sample numerics: ``numpy`` (the default)
or ``numba`` (these kernels)."""
CHOICES = ("numpy", "numba")


def _choice() -> bool:
    value = os.environ.get(ENV, "numpy").strip().lower() or "numpy"
    if value not in CHOICES:
        raise InvalidInputError(f"{ENV}={os.environ[ENV]!r}: the per-sample numerics are "
                                f"one of {', '.join(CHOICES)} (default numpy)")
    return value == "numba"


active = _choice()
"""True: the callers use the compiled kernels (``IEM_KERNELS=numba``, or :func:`set_active`)."""

_KERNELS = ("route_join_small", "learner_estimate", "sgd_steps", "mass_bin_add",
            "lowpass2_step", "ema_step")
_loaded = False
_lock = threading.Lock()


def set_active(on: bool) -> None:
    """Use the compiled kernels (compiling them now) or the NumPy code, from the next call
    (a process normally chooses once, by :data:`ENV`)."""
    global active
    if on:
        load()
    active = bool(on)


def load() -> None:
    """Compile the kernels, or load them from numba's cache (about 1 s with the cache, 4 s
    without, here; once per process, whichever thread asks first). Where numba finds no
    writable cache directory (``NUMBA_CACHE_DIR``, beside this module, the user's cache
    directory) they are compiled without one, with a warning: a start takes longer, and
    nothing fails."""
    with _lock:
        if not _loaded:
            _compile()


def _compile() -> None:
    global _loaded
    try:
        import numba as nb
    except ImportError as exc:
        raise InvalidInputError(f"{ENV}=numba needs numba, which is not installed here "
                                f"(pip install '.[fast]'), or unset {ENV} for the NumPy "
                                f"code") from exc

    f1 = nb.float64[:]  # written to
    f2 = nb.float64[:, :]
    r1 = nb.types.Array(nb.float64, 1, "A", readonly=True)  # only read: a writable array
    r2 = nb.types.Array(nb.float64, 2, "A", readonly=True)  # or a read-only one (tandem
    rc2 = nb.types.Array(nb.float64, 2, "C", readonly=True)  # samples, a joint state)
    signatures = {
        "route_join_small": nb.types.UniTuple(nb.int64, 2)(
            f2, nb.int64[:], nb.int64, r1, r1, nb.float64, nb.float64),
        "learner_estimate": nb.types.UniTuple(nb.float64, 2)(
            r2, r1, r1, r1, r1, r1, r2, nb.boolean, r1, f1),
        "sgd_steps": nb.float64(nb.float64[:, ::1], f1, rc2, r2, nb.float64, nb.int64),
        "mass_bin_add": nb.void(f2, nb.int64[:], r1, r1, r2),
        "lowpass2_step": nb.float64[::1](r2, f2, r1),
        "ema_step": nb.boolean(f1, r1, nb.int64, nb.float64),
    }
    module = globals()
    module["_flange_d2"] = nb.njit(inline="always")(_flange_d2_py)  # inlined in the kernel
    try:
        compiled = {name: nb.njit(signatures[name], cache=True)(module["_" + name])
                    for name in _KERNELS}
    except RuntimeError as exc:  # no writable place for numba's cache (a read-only
        if "no locator" not in str(exc):  # install, no home directory: a hardened unit)
            raise
        log.warning("numba cannot cache the compiled kernels (%s): they are compiled at "
                    "every start (a few seconds). Set NUMBA_CACHE_DIR to a writable "
                    "directory (deploy/iem.service sets it to its state directory).", exc)
        compiled = {name: nb.njit(signatures[name])(module["_" + name]) for name in _KERNELS}
    module.update(compiled)
    _loaded = True


def _on_first_call(name: str):
    def first_call(*args):
        load()  # replaces this module's attribute by the compiled kernel
        return globals()[name](*args)

    first_call.__name__ = name
    return first_call


def _route_join_small(means, counts, n, q, flange, delta2, rho2):
    """:meth:`iem.router.BagRouter.route_join` among ``n`` bags by exact distances.

    ``means`` ``(cap, 10)`` are the bags' ``[q (7), flange (3)]`` means, ``counts`` their
    points, ``q`` (7) and ``flange`` (3) the point. Returns ``(bag, nearest)``: the nearest
    bag in joint space whose two spheres (squared radii ``delta2``, ``rho2``) hold the
    point, or -1, and the nearest bag in joint space (ties: the lowest index). If the point
    is in a bag, that bag's means move toward it and its count grows by one (Algorithm 1).
    """
    d2q = np.empty(n)  # squared joint-space distances, each computed once
    for i in range(n):
        s = 0.0
        for j in range(7):
            d = means[i, j] - q[j]
            s += d * d
        d2q[i] = s
    nearest = 0
    for i in range(1, n):  # argmin: the first of equals, and the first NaN if any
        if d2q[nearest] != d2q[nearest]:
            break
        if d2q[i] < d2q[nearest] or d2q[i] != d2q[i]:
            nearest = i
    bag = -1
    if d2q[nearest] < delta2 and _flange_d2(means, nearest, flange) < rho2:
        bag = nearest  # the usual case: the nearest bag qualifies
    else:
        best_in = np.inf
        for i in range(n):
            if d2q[i] < delta2 and d2q[i] < best_in and _flange_d2(means, i, flange) < rho2:
                best_in = d2q[i]
                bag = i
        if bag < 0:
            return -1, nearest
    k = counts[bag] + 1
    for j in range(7):
        means[bag, j] += (q[j] - means[bag, j]) / k
    for j in range(3):
        means[bag, 7 + j] += (flange[j] - means[bag, 7 + j]) / k
    counts[bag] = k
    return bag, nearest


def _flange_d2_py(means, i, flange):
    """Squared Cartesian distance of ``flange`` to bag ``i``'s flange mean."""
    s = 0.0
    for j in range(3):
        d = means[i, 7 + j] - flange[j]
        s += d * d
    return s


_flange_d2 = _flange_d2_py  # until load() compiles it (to be inlined in the kernel)


def _learner_estimate(a, b, center, inv_scale, lo, span, dq_precision, velocity, x,
                     phi):
    """A weak learner's estimate at input ``x = [q, dq, tau]`` (21) into ``phi`` (10):
    ``lo + ReLU(a z + b) * span`` with ``z = (x - center) * inv_scale``.

    Returns ``(score, velocity_score)``: the largest ``|z|`` (the out-of-distribution
    score) and, if ``velocity``, ``sqrt(max(0, d^T P d) / 7)`` with ``d`` the velocities less
    the centre's and ``P`` ``dq_precision`` (7, 7); 0.0 otherwise.
    """
    n_in = x.shape[0]
    z = np.empty(n_in)
    score = 0.0
    for j in range(n_in):
        z[j] = (x[j] - center[j]) * inv_scale[j]
        if not abs(z[j]) <= score:  # a NaN input makes the score NaN, as NumPy's max
            score = abs(z[j]) if score == score else score
    for i in range(a.shape[0]):
        s = 0.0
        for j in range(n_in):
            s += a[i, j] * z[j]
        y = s + b[i]
        phi[i] = lo[i] + (y if y > 0.0 else 0.0) * span[i]
    vscore = 0.0
    if velocity:
        m = 0.0
        for i in range(7):
            di = x[7 + i] - center[7 + i]
            row = 0.0
            for j in range(7):
                row += dq_precision[i, j] * (x[7 + j] - center[7 + j])
            m += di * row
        vscore = np.sqrt(max(0.0, m) / 7.0)
    return score, vscore


def _sgd_steps(a, b, x, t, step, iters):
    """``iters`` steps of :meth:`iem.learner.WeakLearner.learn`'s SGD on scaled inputs ``x``
    ``(N, 21)`` and scaled targets ``t`` ``(N, 10)``, in place on ``a`` ``(10, 21)`` and
    ``b`` (10): ``a -= step (r^T x)``, ``b -= step sum_k r_k`` with ``r`` the residual
    ``ReLU(x a^T + b) - t``, zero where the ReLU is inactive. The products are BLAS's, as
    NumPy's. Returns the last step's loss ``sum r² / N`` (over every output)."""
    n = x.shape[0]
    k = a.shape[0]
    loss = np.nan
    for it in range(iters):
        z = x @ a.T
        last = it == iters - 1
        total = 0.0
        for r in range(n):
            for i in range(k):
                s = z[r, i] + b[i]
                res = (s if s > 0.0 else 0.0) - t[r, i]
                if last:
                    total += res * res
                z[r, i] = res if s > 0.0 else 0.0
        if last:
            loss = total / n
        g = z.T @ x
        for i in range(k):
            gb = 0.0
            for r in range(n):
                gb += z[r, i]
            for j in range(a.shape[1]):
                a[i, j] -= step * g[i, j]
            b[i] -= step * gb
    return loss


def _mass_bin_add(bin_sq, bin_n, edges, mass, errors):
    """Add the squared ``errors`` ``(K, 10)`` of samples whose payloads weigh ``mass`` (K)
    to their mass bin's row of ``bin_sq`` and count them in ``bin_n``: bin ``k`` is the
    number of ``edges`` at or below the mass (NumPy's ``searchsorted(edges, mass,
    side="right")``; a NaN mass goes to the last bin, as there). Row by row, in order:
    ``np.add.at``'s sums."""
    for r in range(errors.shape[0]):
        k = 0
        m = mass[r]
        while k < edges.shape[0] and (edges[k] <= m or m != m):
            k += 1
        for j in range(errors.shape[1]):
            bin_sq[k, j] += errors[r, j] * errors[r, j]
        bin_n[k] += 1


def _lowpass2_step(m, s, x):
    """One sample ``x`` (channels) through :class:`iem.filters.LowPass2`'s transposed direct
    form II: ``[y, z1', z2'] = m @ [x, z1, z2]`` per channel, ``s`` ``(3, channels)`` its
    rows ``[x, z1, z2]`` (updated in place). Returns ``y``."""
    y = np.empty(x.shape[0])
    for c in range(x.shape[0]):
        xc = x[c]
        z1 = s[1, c]
        z2 = s[2, c]
        s[0, c] = xc
        y[c] = m[0, 0] * xc + m[0, 1] * z1 + m[0, 2] * z2
        s[1, c] = m[1, 0] * xc + m[1, 1] * z1 + m[1, 2] * z2
        s[2, c] = m[2, 0] * xc + m[2, 1] * z1 + m[2, 2] * z2
    return y


def _ema_step(s, x, n, alpha):
    """:class:`iem.smoothing.ExponentialSmoother`'s step on its average ``s`` (in place):
    if every value of ``x`` is finite, ``s += max(1 / (n + 1), alpha) (x - s)`` and True
    (``n``: the estimates averaged so far); else nothing and False."""
    for j in range(x.shape[0]):
        if not np.isfinite(x[j]):
            return False
    c = max(1.0 / (n + 1), alpha)
    for j in range(x.shape[0]):
        s[j] += c * (x[j] - s[j])
    return True


for _name in _KERNELS:  # until load(): compile on the first call
    globals()[_name] = _on_first_call(_name)
del _name
