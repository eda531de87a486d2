"""The plug-in's configuration, ``cell.toml``: its sections as settings
(:mod:`.sections`: a frozen dataclass per section, :class:`CellConfig` holding them, and the
tables of valid values), the ``[arm]`` section's checks across sections (:mod:`.arm`: the arm
model a link implies, its rated payload, the end effector's mass), reading a file
(:mod:`.load`: every key checked, relative paths taken from the file's folder), and a cell's
configuration built in code from its arm model and rating (:mod:`.build`).

Every key is documented in ``deploy/cell.toml``; an error names the key, the value found and
what would be valid (:class:`ConfigError`).
"""

from .build import cell_config, cell_sections
from .load import config_from_dict, load_config
from .sections import (
    CHOICES,
    DERIVED_GATE_KEYS,
    INT_RANGES,
    LINK_KINDS,
    LOG_FORMATS,
    LOG_LEVELS,
    MAY_BE_EMPTY,
    MODEL_KINDS,
    RANGES,
    RETIRED_GATE_KEYS,
    ROS_NAME,
    ROS_NAMES,
    SECTIONS,
    STATUS_MODES,
    ArmConfig,
    CellConfig,
    ConfigError,
    EstimateConfig,
    HostConfig,
    LinkConfig,
    LogConfig,
    ModelConfig,
    Ros2Config,
)

__all__ = ["CHOICES", "DERIVED_GATE_KEYS", "INT_RANGES", "LINK_KINDS", "LOG_FORMATS",
           "LOG_LEVELS", "MAY_BE_EMPTY", "MODEL_KINDS", "RANGES", "RETIRED_GATE_KEYS",
           "ROS_NAME", "ROS_NAMES", "SECTIONS", "STATUS_MODES", "ArmConfig", "CellConfig",
           "ConfigError", "EstimateConfig", "HostConfig", "LinkConfig", "LogConfig",
           "ModelConfig", "Ros2Config", "cell_config", "cell_sections", "config_from_dict",
           "load_config"]
