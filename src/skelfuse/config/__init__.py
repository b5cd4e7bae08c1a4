"""The rig configuration: one typed, frozen :class:`RigConfig`, validated when it is loaded.

A rig config is a TOML file (see ``docs/configuration.md`` for every option, and ``config/rig-*.toml`` for
examples). It describes one installation: its name, its sensors (where frames come from and where each
sensor stands), how frames of one instant are grouped, how they are fused, how nodes talk over zenoh, and
what the fusion node shows and records. Every node of the rig (capture workers, fusion node) reads the same
file, so they agree on names and keys.

Cycle::

    load_rig_config(path)          TOML -> dict (tomllib)
      parse_rig_config(...)        dict -> frozen dataclasses; every key checked (type, range, unknown keys)
    cfg.poses()                    world_from_sensor per sensor (calibration file, else inline poses)
    cfg.fusion.params()            skelfuse.fusion.presets.FusionParams (preset + overrides)
    zenoh_config(cfg, overrides)   zenoh.Config: file < flags < ``--zenoh-cfg KEY:VALUE``

Conventions: units are in the names (``tolerance_ms``, ``delay_us``, ``eps_mm``); ``None`` means "off" or
"not set" and is written in TOML by leaving the key out (never ``-1``). Relative paths are resolved against
the directory of the config file. Every problem raises :class:`skelfuse.schema.errors.ConfigError` naming the
file, the key path (``sensors[2].sync.delay_us``), what was expected and what was found, with a "did you
mean" for a misspelt key.

Modules: ``model`` (the dataclasses), ``parse`` (TOML -> model, section by section), ``checks`` (the
validation primitives), ``calibration_file`` (the rig's versioned calibration file, read and written),
``zenoh_session`` (the zenoh session config of a node).

The names below are the package's re-exports, listed once: the import statements are the list (ruff's
F401 is off for this file, in pyproject.toml).
"""

from skelfuse.config.calibration_file import load_calibration
from skelfuse.config.model import (
    CONGESTION_CONTROLS,
    DEFAULT_PRESET,
    FUSION_PRESETS,
    MIN_DELAY_SPACING_US,
    SOURCE_KINDS,
    ZENOH_MODES,
    CalibrationConfig,
    CaptureConfig,
    DepthConfig,
    FusionConfig,
    IntakeConfig,
    KinectConfig,
    NodeConfig,
    RecordConfig,
    ReplayConfig,
    RerunConfig,
    RigConfig,
    SensorConfig,
    SensorSyncConfig,
    SimConfig,
    StreamConfig,
    SyncConfig,
    TrackerConfig,
    ZenohSection,
)
from skelfuse.config.parse import load_rig_config, parse_rig_config
from skelfuse.config.zenoh_session import zenoh_config
