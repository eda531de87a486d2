"""Loads as ``geometry_msgs/msg/Inertia`` for the ``ros2`` link (extra ``ros2``): the paper's
``phi`` to the message's values and their standard deviations (the estimate topics), and a
message back to a load (franka_ros2's report of the load in force).

``geometry_msgs/msg/Inertia`` holds the mass (kg), the CoM (m) and the inertia about the CoM
(kg·m²), in the frame its header names; ``phi`` holds the inertia about the flange origin.
"""

from __future__ import annotations

import math

import numpy as np

from iem.payload import Payload


def stamp(t: float):
    """``builtin_interfaces/msg/Time`` of ``t`` s."""
    from .ros2_types import Time

    sec = math.floor(t)
    nanosec = min(round((t - sec) * 1e9), 999_999_999)
    return Time(sec=int(sec), nanosec=nanosec)


def inertia_values(phi) -> np.ndarray:
    """``[m, cx, cy, cz, Ixx, Ixy, Ixz, Iyy, Iyz, Izz]`` (kg, m, kg·m² about the CoM) of the
    paper's ``phi`` (inertia about the flange); ValueError if the mass is not > 0."""
    phi = np.asarray(phi, dtype=float)
    m = phi[0]
    if not m > 0.0:
        raise ValueError(f"mass {m} kg is not > 0: no CoM")
    c = phi[1:4] / m
    xx, xy, xz, yy, yz, zz = phi[4:]
    about_o = np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])
    about_c = about_o - m * (float(c @ c) * np.eye(3) - np.outer(c, c))
    return np.concatenate(([m], c, about_c[[0, 0, 0, 1, 1, 2], [0, 1, 2, 1, 2, 2]]))


def inertia_std(phi, std) -> np.ndarray:
    """Standard deviations of :func:`inertia_values` from those of ``phi``, to first order,
    the parameters taken as independent (the models report no covariance)."""
    phi = np.asarray(phi, dtype=float)
    base = inertia_values(phi)
    jac = np.empty((10, 10))
    for j in range(10):
        h = 1e-7 * max(1.0, abs(phi[j]))
        d = phi.copy()
        d[j] += h
        jac[:, j] = (inertia_values(d) - base) / h
    return np.sqrt((jac ** 2) @ (np.asarray(std, dtype=float) ** 2))


def inertia_message(values, frame_id: str, t: float):
    """An ``InertiaStamped`` of :func:`inertia_values`-ordered ``values`` at ``t`` s."""
    from .ros2_types import Header, Inertia, InertiaStamped, Vector3

    v = [float(x) for x in values]
    return InertiaStamped(header=Header(stamp=stamp(t), frame_id=frame_id),
                          inertia=Inertia(m=v[0], com=Vector3(v[1], v[2], v[3]), ixx=v[4],
                                          ixy=v[5], ixz=v[6], iyy=v[7], iyz=v[8], izz=v[9]))


def load_of(inertia, name: str = "in force") -> Payload | None:
    """The load of a ``geometry_msgs/msg/Inertia``: None for the empty load (mass 0, as
    libfranka reports no load), else a :class:`Payload` (not checked for consistency: it
    is what the robot says it holds)."""
    if not inertia.m > 0.0:
        return None
    com = inertia.com
    return Payload(name=name, mass=inertia.m, com=(com.x, com.y, com.z),
                   inertia=(inertia.ixx, inertia.ixy, inertia.ixz, inertia.iyy, inertia.iyz,
                            inertia.izz))
