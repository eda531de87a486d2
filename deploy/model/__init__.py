"""The model a cell runs: making the initial one (:mod:`.training`: bags and learners from
the excitation path on the tandem simulators of the configured family and arm, ``iem train``'s
library), and setting up the configured one (:mod:`.setup`: the link's rate and block points,
the model file loaded or trained, checked against the arm and the family, started from a
payload file).
"""

from .setup import (
    INITIAL_STD,
    block_frames_of,
    checked_model,
    link_rate,
    load_or_train_model,
    model_resources,
    point_rate,
    start_from_file,
)
from .training import (
    DEPLOY_ENSEMBLE,
    NOISE_SOURCES,
    arm_torque_noise,
    check_model_arm,
    check_model_family,
    check_model_rate,
    excitation,
    load_arm_file,
    make_model,
    tandem_for,
    train_initial_model,
)

__all__ = ["DEPLOY_ENSEMBLE", "INITIAL_STD", "NOISE_SOURCES", "arm_torque_noise",
           "block_frames_of", "check_model_arm", "check_model_family",
           "check_model_rate", "checked_model", "excitation", "link_rate", "load_arm_file",
           "load_or_train_model", "make_model", "model_resources", "point_rate",
           "start_from_file", "tandem_for", "train_initial_model"]
