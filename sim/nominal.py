"""The arm description's Pinocchio model, built once per description and shared: the model
itself (with or without what hangs beyond the flange), the bodies from joint 7 to the
flange, and the flange frame in the joint-7 frame. :mod:`sim.robot` builds its
:class:`~sim.robot.ArmModel` on it and :mod:`sim.end_effector` takes the flange and body 7
from it."""

from __future__ import annotations

from functools import cache

import numpy as np
import pinocchio as pin

from .description import ArmDescription, described


@cache
def pin_model(description: ArmDescription, full: bool) -> pin.Model:
    """The Pinocchio model of ``description``: its text (``full``: with what hangs beyond the
    flange, the joints there locked at zero)."""
    from iem.errors import InvalidInputError

    text = description.full_text if full else description.text
    try:
        model = pin.buildModelFromXML(text)
    except (RuntimeError, ValueError) as exc:
        raise InvalidInputError(f"arm model {description.source}: Pinocchio cannot read it: "
                                f"{exc}") from exc
    locked = [model.getJointId(n) for n in description.locked if model.existJointName(n)]
    if locked:
        model = pin.buildReducedModel(model, locked, pin.neutral(model))
    names = tuple(model.names[1:])
    if model.nq != 7 or model.nv != 7 or names != description.joint_names:
        raise InvalidInputError(f"arm model {description.source}: Pinocchio reads joints "
                                f"{names} (nq {model.nq}, nv {model.nv}), the description's "
                                f"arm joints are {description.joint_names}")
    return model


def nominal_model(description=None) -> pin.Model:
    """The Pinocchio model of the arm ``description`` (None: the default arm model) with what
    hangs beyond the flange (its own end effector, if any), cached."""
    return pin_model(described(description), True)


def link7_params(description=None) -> np.ndarray:
    """``(10,)`` Pinocchio dynamic parameters of body 7 without any end effector (the bodies
    from joint 7 to the flange, joint-7 frame)."""
    out = pin_model(described(description), False).inertias[7].toDynamicParameters()
    out.flags.writeable = False
    return out


def flange_placement(description=None) -> pin.SE3:
    """The flange frame in the joint-7 frame."""
    desc = described(description)
    model = pin_model(desc, False)
    return model.frames[model.getFrameId(desc.flange)].placement.copy()
