"""The observation model's parameters: :class:`SimProfile`, its per-group noise tables and its TOML loader.

Every field is documented in the packaged default ``skelfuse/profiles/azure_kinect.toml``, which says where
each value comes from; :func:`load_profile` validates a file against the dataclass and names the bad key.
"""

from __future__ import annotations

import dataclasses
import tomllib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from skelfuse.schema.errors import ConfigError
from skelfuse.schema.skeleton import BODY_REGIONS, N_JOINTS

NOISE_GROUPS: tuple[str, ...] = tuple(BODY_REGIONS)
"""Joint groups of the per-group noise tables (see :data:`JOINT_NOISE_GROUP`)."""

JOINT_NOISE_GROUP = np.zeros(N_JOINTS, dtype=np.int64)
"""(32,) index into :data:`NOISE_GROUPS` of every joint."""
for _group_idx, _group in enumerate(NOISE_GROUPS):
    JOINT_NOISE_GROUP[BODY_REGIONS[_group]] = _group_idx

CAPSULES = (
    ("spine", "PELVIS", "NECK"),
    ("torso_side", "HIP_LEFT", "SHOULDER_LEFT"),
    ("torso_side", "HIP_RIGHT", "SHOULDER_RIGHT"),
    ("head", "HEAD", "HEAD"),
    ("upper_arm", "SHOULDER_LEFT", "ELBOW_LEFT"),
    ("upper_arm", "SHOULDER_RIGHT", "ELBOW_RIGHT"),
    ("forearm", "ELBOW_LEFT", "WRIST_LEFT"),
    ("forearm", "ELBOW_RIGHT", "WRIST_RIGHT"),
    ("thigh", "HIP_LEFT", "KNEE_LEFT"),
    ("thigh", "HIP_RIGHT", "KNEE_RIGHT"),
    ("shin", "KNEE_LEFT", "ANKLE_LEFT"),
    ("shin", "KNEE_RIGHT", "ANKLE_RIGHT"),
)
"""Body capsules for self-occlusion: (radius key in ``capsule_radius_mm``, start joint, end joint)."""


def _groups(**values: float) -> Any:
    return lambda: dict(values)


_SECTIONS: dict[str, tuple[str, ...]] = {
    "timing": (
        "fps",
        "frame_interval_jitter_us",
        "device_time_start_us",
        "subordinate_delay_us",
        "subordinate_delay_spread_us",
        "dropped_frame_prob",
        "host_epoch_s",
        "host_latency_mean_ms",
        "host_latency_jitter_ms",
        "host_offset_sd_ms",
    ),
    "tracking": ("min_torso_joints_in_view", "convergence_frames", "convergence_sigma_mm"),
    "noise": (
        "slow_rho",
        "slow_sigma_mm",
        "white_sigma_mm",
        "white_dof",
        "jump_prob",
        "jump_sigma_mm",
        "offset_sigma_mm",
    ),
    "occlusion": (
        "capsule_radius_mm",
        "occlusion_margin_mm",
        "occluded_low_prob",
        "occluded_rho",
        "occluded_sigma_mm",
        "occluded_jump_prob",
        "occluded_pull",
        "torso_occluded_low_prob",
    ),
    "mirroring": (
        "away_threshold_deg",
        "hysteresis_deg",
        "front_free_deg",
        "flip_on_prob",
        "flip_off_prob_away",
        "flip_off_prob_front",
    ),
    "confidence": (
        "hand_none_fraction_min",
        "hand_none_fraction_max",
        "hand_none_rho",
        "leg_low_prob",
        "leg_low_length_alpha",
        "leg_low_max_frames",
    ),
    "scale": (
        "scale_view_sd",
        "scale_view_max",
        "scale_slow_sd",
        "scale_slow_rho",
        "scale_per_100mm_drop",
        "scale_max_shrink",
    ),
    "calibration": ("calibration_rotation_sd_deg", "calibration_translation_sd_mm"),
    "failures": (
        "limb_swap_prob",
        "limb_swap_off_prob",
        "side_flip_prob",
        "side_flip_min_deg",
        "flip_restarts_fit",
        "common_offset_sigma_mm",
        "common_slow_sigma_mm",
        "noise_gain_per_m",
        "noise_gain_per_mps",
        "lag_frames",
        "partial_view_drag",
        "mount_tilt_deg",
        "sitting",
        "lying",
        "neighbour_distance_mm",
        "neighbour_swap_prob",
        "neighbour_merge_prob",
        "neighbour_off_prob",
        "tracker_loss_prob",
        "tracker_loss_flip_frames",
        "tracker_loss_offset_mm",
        "tracker_loss_away_frames",
    ),
}
"""TOML section of every SimProfile field (sections only organise the file)."""


@dataclass(frozen=True)
class SimProfile:
    """Parameters of the observation model. Units are in the names; per-group tables are keyed by
    :data:`NOISE_GROUPS`. ``load_profile()`` returns the documented default (azure_kinect.toml), where
    every field has a comment saying what it is and where its value comes from.
    """

    # [timing]
    fps: float = 30.0  # device frame rate, Hz
    frame_interval_jitter_us: float = 12.0  # SD of the device frame interval, us
    device_time_start_us: float = 1_000_000.0  # master device timestamp of frame 0, us
    subordinate_delay_us: float = 1000.0  # depth delay per subordinate index, us
    subordinate_delay_spread_us: float = 67.0  # subordinate arrives up to this much early, us
    dropped_frame_prob: float = 0.000167  # per sensor and frame
    host_epoch_s: float = 1.7e9  # host clock at device time 0, s
    host_latency_mean_ms: float = 35.0  # device -> host latency, ms
    host_latency_jitter_ms: float = 3.0  # SD of the latency per frame, ms
    host_offset_sd_ms: float = 2.0  # SD of a constant per-sensor latency part, ms
    # [tracking]
    min_torso_joints_in_view: int = 3  # torso joints in view needed to track
    convergence_frames: float = 8.0  # time constant of initial error, frames
    convergence_sigma_mm: float = 40.0  # per-axis SD of the initial error, mm
    # [noise]
    slow_rho: dict[str, float] = field(
        default_factory=_groups(torso=0.92, head=0.92, face=0.5, arm=0.88, hand=0.85, knee=0.9, foot=0.9)
    )  # AR(1) coefficient per frame
    slow_sigma_mm: dict[str, float] = field(
        default_factory=_groups(torso=3.0, head=2.5, face=8.0, arm=6.0, hand=12.0, knee=5.0, foot=5.5)
    )  # stationary SD of the slow error per axis, mm
    white_sigma_mm: dict[str, float] = field(
        default_factory=_groups(torso=1.5, head=1.5, face=2.0, arm=2.5, hand=3.5, knee=2.0, foot=2.5)
    )  # SD of white jitter per axis, mm
    white_dof: float = 3.0  # Student-t degrees of freedom (> 2)
    jump_prob: float = 0.001  # per joint and frame, impulse into the slow error
    jump_sigma_mm: float = 60.0  # per-axis SD of an impulse, mm
    offset_sigma_mm: dict[str, float] = field(
        default_factory=_groups(torso=2.0, head=2.5, face=11.0, arm=18.0, hand=30.0, knee=10.0, foot=17.0)
    )  # SD of the constant per-view offset per axis, mm
    # [occlusion]
    capsule_radius_mm: dict[str, float] = field(
        default_factory=_groups(
            spine=100.0, torso_side=75.0, head=80.0, upper_arm=45.0, forearm=38.0, thigh=70.0, shin=50.0
        )
    )  # body capsule radii, mm
    occlusion_margin_mm: float = 40.0  # occluder at least this far in front, mm
    occluded_low_prob: float = 1.0  # P(LOW | occluded)
    occluded_rho: float = 0.9  # AR(1) coefficient of the guess error
    occluded_sigma_mm: dict[str, float] = field(
        default_factory=_groups(torso=8.0, head=15.0, face=30.0, arm=45.0, hand=50.0, knee=40.0, foot=45.0)
    )  # per-axis SD of the guess error, mm
    occluded_jump_prob: float = 0.25  # per frame, the guess is redrawn
    occluded_pull: float = 0.3  # pull towards a hanging-limb default pose
    torso_occluded_low_prob: float = 0.0  # P(LOW | occluded) for torso joints (the trunk is seen around a limb)
    # [mirroring]
    away_threshold_deg: float = 110.0  # facing-away angle where flips can start
    hysteresis_deg: float = 20.0  # burst may continue down to threshold - this
    front_free_deg: float = 25.0  # never mirrored within this angle
    flip_on_prob: float = 0.15  # per frame facing away: a burst starts
    flip_off_prob_away: float = 0.02  # per frame facing away: the burst ends
    flip_off_prob_front: float = 0.5  # per frame below threshold - hysteresis
    # [confidence]
    hand_none_fraction_min: float = 0.23  # hands NONE fraction, lower bound
    hand_none_fraction_max: float = 1.0  # hands NONE fraction, upper bound
    hand_none_rho: float = 0.9  # temporal correlation of hand NONE episodes
    leg_low_prob: float = 0.006  # per frame and leg: a LOW episode of an unoccluded knee/ankle/foot starts
    leg_low_length_alpha: float = 1.2  # episode length floor(U ** (-1 / alpha)) frames: heavy-tailed
    leg_low_max_frames: int = 15  # longest episode, frames
    # [scale]
    scale_view_sd: float = 0.015  # SD of a view's size level
    scale_view_max: float = 0.05  # clip of the view level's deviation
    scale_slow_sd: float = 0.008  # SD of the slow size drift
    scale_slow_rho: float = 0.88  # AR(1) coefficient of the drift per frame
    scale_per_100mm_drop: float = 0.015  # shrink per 100 mm of pelvis drop
    scale_max_shrink: float = 0.11  # maximum pose shrink
    # [calibration]
    calibration_rotation_sd_deg: float = 0.75  # SD of the rotation error angle, deg
    calibration_translation_sd_mm: float = 6.0  # SD of the translation error per axis, mm
    # [failures] (all off by default; sim/failures.py names the families that switch them on)
    limb_swap_prob: float = 0.0  # per frame, view not facing away: one limb's left/right labels swap
    limb_swap_off_prob: float = 0.2  # per frame: such a swap ends
    side_flip_prob: float = 0.0  # per frame, view seeing the side: a whole-body mirror burst starts
    side_flip_min_deg: float = 60.0  # side views: facing-away angle from this up to away_threshold_deg
    flip_restarts_fit: float = 0.0  # 1: a mirror burst restarts the fit (convergence transient), 0: it does not
    common_offset_sigma_mm: float = 0.0  # per axis: a constant error of the tracker's body model, shared by all views
    common_slow_sigma_mm: float = 0.0  # per axis: a slow (slow_rho) error shared by all views
    noise_gain_per_m: float = 0.0  # slow and white error grow by this fraction per metre beyond 2 m
    noise_gain_per_mps: float = 0.0  # ... and by this fraction per m/s of the joint's speed
    lag_frames: float = 0.0  # the tracker reports each joint this many frames late (all views)
    partial_view_drag: float = 0.0  # body partly out of view: the rest moves this fraction of the out-of-view guesses
    mount_tilt_deg: float = 0.0  # each sensor rolled and pitched by up to this; its tracker's "down" stays level
    sitting: float = 0.0  # 1: the subject sits (thighs level, shins down, feet on the floor), upper body as moved
    lying: float = 0.0  # 1: the subject lies on the back on the floor, the motion turned 90 deg about the pelvis
    neighbour_distance_mm: float = 0.0  # > 0: a second person this far to the subject's right, 1 s behind in motion
    neighbour_swap_prob: float = 0.0  # per frame, the first sensor: a burst in which it reports the neighbour
    neighbour_merge_prob: float = 0.0  # per frame, the first sensor: a burst in which it merges both into one body
    neighbour_off_prob: float = 0.1  # per frame: such a burst ends
    tracker_loss_prob: float = 0.0  # per frame and view: the tracker loses the person (sim/tracker_loss.py)
    tracker_loss_flip_frames: int = 3  # ... reports them upside down for this many frames
    tracker_loss_offset_mm: float = 350.0  # ... then re-acquires them (new body id) this far off
    tracker_loss_away_frames: int = 10  # ... for this many frames before the fit returns

    def __post_init__(self) -> None:
        _validate(self, "<SimProfile>")

    def replace(self, **changes: Any) -> SimProfile:
        """A copy with some fields changed (validated)."""
        return dataclasses.replace(self, **changes)


if {f.name for f in dataclasses.fields(SimProfile)} != {n for names in _SECTIONS.values() for n in names}:
    raise RuntimeError("SimProfile fields and _SECTIONS disagree")  # a programming error, caught at import

_PROBABILITIES = (
    "dropped_frame_prob",
    "jump_prob",
    "occluded_low_prob",
    "occluded_jump_prob",
    "occluded_pull",
    "flip_on_prob",
    "flip_off_prob_away",
    "flip_off_prob_front",
    "hand_none_fraction_min",
    "hand_none_fraction_max",
    "leg_low_prob",
    "torso_occluded_low_prob",
    "limb_swap_prob",
    "limb_swap_off_prob",
    "side_flip_prob",
    "partial_view_drag",
    "neighbour_swap_prob",
    "neighbour_merge_prob",
    "neighbour_off_prob",
    "tracker_loss_prob",
)
_RHOS = ("occluded_rho", "hand_none_rho", "scale_slow_rho")
_FLAGS = ("flip_restarts_fit", "sitting", "lying")


def _validate(profile: SimProfile, source: str) -> None:
    def bad(key: str, message: str) -> ConfigError:
        return ConfigError(f"{source}: profile key {key!r} {message}")

    for f in dataclasses.fields(profile):
        value = getattr(profile, f.name)
        if isinstance(value, dict):
            expected = set(NOISE_GROUPS) if f.name != "capsule_radius_mm" else {c[0] for c in CAPSULES}
            if set(value) != expected:
                raise bad(f.name, f"must have exactly the keys {sorted(expected)}, got {sorted(value)}")
            values = list(value.values())
        else:
            values = [value]
        for v in values:
            if not np.isfinite(v):
                raise bad(f.name, f"must be finite, got {v!r}")
            if f.name in ("slow_rho", *_RHOS) and not 0.0 <= v < 1.0:
                raise bad(f.name, f"must be in [0, 1), got {v!r}")
            if f.name in _PROBABILITIES and not 0.0 <= v <= 1.0:
                raise bad(f.name, f"must be a probability in [0, 1], got {v!r}")
            if v < 0 and f.name not in ("device_time_start_us",):
                raise bad(f.name, f"must not be negative, got {v!r}")
    if profile.white_dof <= 2.0:
        raise bad("white_dof", f"must be > 2 (finite variance), got {profile.white_dof!r}")
    for name in _FLAGS:
        if getattr(profile, name) not in (0.0, 1.0):
            raise bad(name, f"must be 0 or 1, got {getattr(profile, name)!r}")
    if profile.leg_low_length_alpha <= 0:
        raise bad("leg_low_length_alpha", f"must be positive, got {profile.leg_low_length_alpha!r}")
    if profile.fps <= 0:
        raise bad("fps", f"must be positive, got {profile.fps!r}")
    if profile.hand_none_fraction_min > profile.hand_none_fraction_max:
        raise bad("hand_none_fraction_min", "must not exceed hand_none_fraction_max")
    if profile.mount_tilt_deg > 90.0:
        raise bad("mount_tilt_deg", f"must be at most 90 degrees, got {profile.mount_tilt_deg!r}")
    if profile.sitting and profile.lying:
        raise bad("lying", "and 'sitting' cannot both be 1 (one posture at a time)")


def default_profile_path() -> Path:
    """Path of the packaged default profile, ``skelfuse/profiles/azure_kinect.toml``."""
    return Path(str(resources.files("skelfuse") / "profiles" / "azure_kinect.toml"))


def load_profile(path: str | Path | None = None) -> SimProfile:
    """Load a simulator profile from TOML (``None``: the packaged Azure Kinect default).

    Sections are organisational ([timing], [noise], ...); every key must be a :class:`SimProfile` field of
    that section. Keys left out keep the dataclass default.

    Raises
    ------
    ConfigError
        Missing or unparsable file, unknown section or key, or a value of the wrong type or range; the
        message names the key and the file.
    """
    path = Path(path) if path is not None else default_profile_path()
    try:
        with path.open("rb") as handle:
            data = tomllib.load(handle)
    except OSError as exc:
        raise ConfigError(f"cannot read simulator profile {path}: {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"simulator profile {path} is not valid TOML: {exc}") from None
    fields = {f.name: f for f in dataclasses.fields(SimProfile)}
    section_of = {name: section for section, names in _SECTIONS.items() for name in names}
    sections = set(_SECTIONS)
    values: dict[str, Any] = {}
    for section, table in data.items():
        if section not in sections or not isinstance(table, dict):
            raise ConfigError(f"{path}: unknown section or key {section!r}; expected sections {sorted(sections)}")
        for key, value in table.items():
            f = fields.get(key)
            if f is None or section_of.get(key) != section:
                known = sorted(_SECTIONS[section])
                raise ConfigError(f"{path}: unknown key {section}.{key!r}; keys of [{section}]: {known}")
            values[key] = _coerce(key, value, f, path)
    try:
        profile = SimProfile(**values)
    except ConfigError as exc:
        raise ConfigError(str(exc).replace("<SimProfile>", str(path))) from None
    return profile


def _coerce(key: str, value: Any, f: dataclasses.Field, path: Path) -> Any:
    default = f.default_factory() if f.default is dataclasses.MISSING else f.default  # type: ignore[operator]  # a field without a default has a default_factory here (every profile field has one of them), which the stubs cannot tie together

    def number(v: Any, name: str) -> float:
        if isinstance(v, bool) or not isinstance(v, int | float):
            raise ConfigError(f"{path}: profile key {name!r} must be a number, got {type(v).__name__} {v!r}")
        return float(v)

    if isinstance(default, dict):
        if not isinstance(value, dict):
            raise ConfigError(
                f"{path}: profile key {key!r} must be a table keyed by {sorted(default)}, got {type(value).__name__}"
            )
        unknown = sorted(set(value) - set(default))
        if unknown:
            raise ConfigError(f"{path}: profile key {key!r} has unknown entries {unknown}; expected {sorted(default)}")
        return default | {k: number(v, f"{key}.{k}") for k, v in value.items()}
    if isinstance(default, int) and not isinstance(default, bool):
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{path}: profile key {key!r} must be an integer, got {type(value).__name__} {value!r}")
        return value
    return number(value, key)
