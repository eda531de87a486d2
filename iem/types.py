"""Value types that cross the seams between the packages.

The payload parameter vector ``phi`` follows the paper (Eq. 9)::

    phi = [m, m*rx, m*ry, m*rz, Ixx, Ixy, Ixz, Iyy, Iyz, Izz]

in kg, kg·m and kg·m², with the inertia taken about the flange origin in flange axes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .errors import InvalidInputError

PARAMS: tuple[str, ...] = ("m", "mrx", "mry", "mrz", "Ixx", "Ixy", "Ixz", "Iyy", "Iyz", "Izz")
"""Names of the ten payload parameters, in the paper's order."""

GROUPS: dict[str, tuple[int, ...]] = {
    "mass": (0,),
    "com": (1, 2, 3),
    "inertia": (4, 5, 6, 7, 8, 9),
}
"""Parameter groups used for the paper's summary figures (indices into ``PARAMS``)."""

N_JOINTS = 7

NOMINAL_RATE_HZ = 1000.0
"""The controller's nominal joint-state rate, Hz: a Franka's 1 kHz cycle (libfranka's
RobotState, franka_ros2's ``/franka/joint_states``, the ``fd`` wire profile of
``protocol.dbc``). What a link really delivers is ``firmware_bridge.links.rate_hz`` (the
``classic`` profile's is 500 Hz)."""

DEFAULT_BLOCK_FRAMES = 10
"""Frames per block point (:mod:`iem.signals.blocks`): the estimator works on the means of this many
consecutive frames (the plug-in's ``[estimate] block_frames``)."""

NOMINAL_POINT_RATE_HZ = NOMINAL_RATE_HZ / DEFAULT_BLOCK_FRAMES
"""Block points per second from a 1 kHz controller: the default rate of every filter and
estimator of the estimation path (100 Hz)."""


def vec7(name: str, value, error: type[InvalidInputError] = InvalidInputError,
         finite: bool = False) -> np.ndarray:
    """``value`` as a read-only float64 array of one number per joint (7), or ``error``
    naming ``name`` and what is valid; ``finite``: NaN and infinity refused too. A read-only
    float64 (7) array (as a :class:`JointState` keeps) is returned as it is."""
    if type(value) is np.ndarray and value.dtype == np.float64 and value.shape == (N_JOINTS,) \
            and not value.flags.writeable and not finite:
        return value  # already what we keep: read-only float64 (7)
    try:
        arr = np.array(value, dtype=float).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise error(f"{name} must be {N_JOINTS} numbers, got {type(value).__name__}") from exc
    if arr.shape != (N_JOINTS,):
        raise error(f"{name} must have shape ({N_JOINTS},), got {arr.shape}")
    if finite and not np.all(np.isfinite(arr)):
        raise error(f"{name} must be {N_JOINTS} finite numbers, got {arr}")
    arr.flags.writeable = False
    return arr


_set = object.__setattr__  # how a frozen dataclass sets its fields


@dataclass(frozen=True)
class JointState:
    """One controller cycle as a Franka reports it.

    Attributes:
        t: controller time stamp in s.
        q: measured joint positions in rad (7).
        dq: measured joint velocities in rad/s (7).
        tau_J: measured link-side joint torques in N·m (7), after the gears.
        cycle: controller cycle counter (wraps as the wire protocol defines).
    """

    t: float
    q: np.ndarray
    dq: np.ndarray
    tau_J: np.ndarray
    cycle: int = 0

    def __post_init__(self) -> None:
        object.__setattr__(self, "q", vec7("q", self.q))
        object.__setattr__(self, "dq", vec7("dq", self.dq))
        object.__setattr__(self, "tau_J", vec7("tau_J", self.tau_J))

    @classmethod
    def of_kept(cls, t: float, q: np.ndarray, dq: np.ndarray, tau_J: np.ndarray,
                cycle: int = 0) -> JointState:
        """A state of arrays that already are what a state keeps (read-only float64, 7
        each; ``t`` a float, ``cycle`` an int), taken as they are: for a decoder or a former
        that made them so, once a frame or a block, where the checks would only repeat."""
        self = object.__new__(cls)
        _set(self, "t", t)
        _set(self, "q", q)
        _set(self, "dq", dq)
        _set(self, "tau_J", tau_J)
        _set(self, "cycle", cycle)
        return self

    def features(self) -> np.ndarray:
        """The learner input ``X = [q, dq, tau]`` (21 values), as in the paper (Eq. 10-12)."""
        return np.concatenate((self.q, self.dq, self.tau_J))


@dataclass(frozen=True)
class PayloadEstimate:
    """An estimate of the payload parameters at one instant, with what the safety gate needs
    to judge it.

    The gate fails closed: it writes only an estimate that reports its standard deviations,
    its data's verdict and its out-of-distribution verdict (``std``, ``nis``, ``ood`` not
    None), unless the cell allows writing without them (``[gate]
    allow_without_uncertainty``). A model that cannot say one of them passes None for it,
    explicitly: the fields are typed, so a misspelt or forgotten one is an error where the
    estimate is made, never a write let through.

    Attributes:
        t: time of the joint state it was made from, in s.
        phi: parameters in the paper's order (see module docstring), units kg, kg·m, kg·m².
        std: one standard deviation per parameter, same units; None: the model has none.
        bag: index of the bag whose learner made it, or -1 if no bag was involved.
        learning: True if the learner was trained on this instant before predicting.
        nis: the mean normalised innovation squared per degree of freedom of the model's
            recent equations (about 1 while the data agree with it; NaN: no verdict yet);
            None: the model does not test its data.
        ood: True if the estimate comes from an input beyond what its learner was trained
            on; None: the model cannot say.
        unverified: True while an estimate started from a payload file has not yet been
            tested against enough live data.
        determined: the parameter groups (:data:`GROUPS`) the data determine; the others are
            the prior's; None: the model cannot say.
        cov: the covariance of ``phi`` (10x10, ``std`` its diagonal's square root), where the
            model has one: the gate bounds the joint-torque error of a write with it; None:
            the standard deviations alone (correlations unknown).
        prior: the parameters of the prior the estimate started from (10, paper order),
            where the model has one: a group the data do not determine (``determined``) is
            written as the prior has it; None: the model has none (the gate then writes no
            estimate whose inertia the data do not determine).
        extra: diagnostics that no safety decision reads (``change``, ``reset``,
            ``ood_score``, ``velocity_score``, ``held``; ``mean_mass``: a model that projects
            its estimate onto possible bodies gives the mass before the projection, which
            the arm watch reads: a bare arm through a wrong end effector reads below zero).
    """

    t: float
    phi: np.ndarray
    std: np.ndarray | None = None
    bag: int = -1
    learning: bool = False
    nis: float | None = None
    ood: bool | None = None
    unverified: bool = False
    determined: tuple[str, ...] | None = None
    extra: dict = field(default_factory=dict, compare=False)
    cov: np.ndarray | None = field(default=None, compare=False)
    prior: np.ndarray | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        """Check the contract where the estimate is made: ``phi`` 10 finite numbers (or all
        NaN: no estimate yet), ``std`` None or 10 numbers ``>= 0`` (inf: nothing known along
        that parameter), ``nis`` None, NaN or ``>= 0``.

        Raises:
            InvalidInputError: naming the field, what it holds and what is valid.
        """
        phi = np.asarray(self.phi, dtype=float)
        if phi.shape != (10,):
            raise InvalidInputError(f"PayloadEstimate.phi has shape {phi.shape}; valid is (10,)")
        if not np.isfinite(phi).all() and not np.isnan(phi).all():
            raise InvalidInputError("PayloadEstimate.phi has NaN or infinite entries; valid is "
                                    "10 finite numbers, or all NaN for no estimate yet")
        if self.std is not None:
            std = np.asarray(self.std, dtype=float)
            if std.shape != (10,):
                raise InvalidInputError(f"PayloadEstimate.std has shape {std.shape}; valid is "
                                        "(10,) or None")
            if not std.min() >= 0:  # NaN fails too (the minimum of a NaN is NaN)
                raise InvalidInputError(f"PayloadEstimate.std has a negative or NaN entry "
                                        f"({std.min():.4g}); valid is >= 0 or inf")
        if self.cov is not None:
            cov = np.asarray(self.cov, dtype=float)
            if cov.shape != (10, 10) or not np.isfinite(cov).all() or cov.diagonal().min() < 0:
                raise InvalidInputError(f"PayloadEstimate.cov has shape {cov.shape} or a "
                                        "non-finite or negative-variance entry; valid is a "
                                        "finite 10x10 covariance or None")
        if self.nis is not None and not (math.isnan(self.nis) or self.nis >= 0):
            raise InvalidInputError(f"PayloadEstimate.nis = {self.nis!r}; valid is >= 0, NaN "
                                    "(no verdict yet) or None")
