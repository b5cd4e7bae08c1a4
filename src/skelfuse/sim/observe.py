"""Observation model: what each virtual Azure Kinect body tracker reports for a true motion.

Cycle, per sensor (numpy over frames and joints; Python loops only over sensors, joints along the
kinematic chain, and scalar per-frame state machines):

1. truth → sensor frame; field of view and depth range per joint; the body is tracked only while enough
   torso joints are in view; dropped frames.
2. Self-occlusion: rays from the sensor to every joint against capsules around the same body's bones.
3. Facing: a body facing away is mirrored in bursts (Markov chain with hysteresis); a burst starts with a
   new body id. A mirrored fit also puts the face and toes on the sensor's side.
4. Error, in the tracker's label space: constant per-view offsets + slow AR(1) + heavy-tailed white jitter
   + rare jumps; occluded or out-of-view joints get the tracker's guess instead (pulled towards a default
   pose, with a large AR(1) error that jumps); newly found bodies converge over a few frames.
5. Body model: the noisy joints are refitted along the kinematic chain to fixed (left/right symmetric)
   bone lengths times ONE size factor per frame and view (view level, slow drift, shrink with pelvis drop).
6. Confidence labels, body ids, device and host timestamps, calibrated extrinsics with error.

Every parameter lives in :class:`SimProfile`, loaded from TOML (the packaged default is
``skelfuse/profiles/azure_kinect.toml``, which says where each default comes from).
"""

from __future__ import annotations

import dataclasses
import tomllib
import zlib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
from scipy.signal import lfilter
from scipy.special import ndtri

from skelfuse.fusion.transform import apply_transform
from skelfuse.schema.errors import ConfigError
from skelfuse.schema.skeleton import (
    BODY_REGIONS,
    BONES,
    MIRROR,
    N_JOINTS,
    PARENTS,
    TORSO_TRACKING_JOINTS,
    Confidence,
    J,
)
from skelfuse.sim.motion import Motion, root_facing
from skelfuse.sim.rig import VirtualSensor
from skelfuse.sim.tracker_loss import apply_tracker_loss, tracker_loss_episodes

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

_TORSO_CAPSULE = np.array([c[0] in ("spine", "torso_side") for c in CAPSULES])
_CAN_HIDE = ~(np.isin(np.arange(N_JOINTS), BODY_REGIONS["torso"])[:, None] & _TORSO_CAPSULE)
"""(32, C) whether capsule c can hide joint j: torso joints lie inside the trunk, which the tracker sees through
its surface, so only limbs and the head can hide them."""
_HAND_SIDES = tuple(np.array([J[f"{n}_{side}"] for n in ("HAND", "HANDTIP", "THUMB")]) for side in ("LEFT", "RIGHT"))
_LEG_CHAINS = tuple(np.array([J[f"{n}_{side}"] for n in ("KNEE", "ANKLE", "FOOT")]) for side in ("LEFT", "RIGHT"))
_TORSO_JOINTS_MASK = np.isin(np.arange(N_JOINTS), BODY_REGIONS["torso"])
_LIMB_CHAINS = tuple(
    tuple(np.array([J[f"{name}_{side}"] for name in names]) for side in ("LEFT", "RIGHT"))
    for names in (("ELBOW", "WRIST", "HAND", "HANDTIP", "THUMB"), ("KNEE", "ANKLE", "FOOT"))
)
"""(left, right) joint chains of the arms and of the legs: what a single-limb left/right swap exchanges."""
_FACE_JOINTS = BODY_REGIONS["face"]
_FOOT_TIPS = np.array([J["FOOT_LEFT"], J["FOOT_RIGHT"]])


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


@dataclass(frozen=True)
class Observations:
    """What the rig's body trackers reported for one take (one person), plus the ground truth.

    T frames at the profile's frame rate, S sensors in the order given to :func:`simulate` (index 0 is
    the master). Joint arrays follow the k4abt order and hold the tracker's *labels*: where ``mirrored``
    is true, index ``WRIST_LEFT`` holds the subject's right wrist.

    Attributes
    ----------
    sensor_ids : tuple[str, ...]
    positions : (T, S, 32, 3) float32, each sensor's own camera frame (x right, y down, z forward), mm;
        NaN where the sensor did not track the body or dropped the frame.
    confidence : (T, S, 32) uint8, :class:`skelfuse.schema.skeleton.Confidence` values (NONE where NaN).
    body_ids : (T, S) int64, the tracker's body id; -1 where not tracked; a new id when the body is found
        again and when a mirrored burst starts.
    tracked : (T, S) bool, the sensor reported the body in that frame.
    mirrored : (T, S) bool, ground truth: the view's left/right labels are swapped.
    device_time_us : (T, S) int64 device timestamps, µs; -1 where the frame was dropped.
    host_time_ns : (T, S) int64 host timestamps, ns; -1 where the frame was dropped.
    world_from_sensor : (S, 4, 4) true extrinsics.
    world_from_sensor_calibrated : (S, 4, 4) extrinsics with the profile's calibration error (the master's
        is exact): what a real rig would use.
    truth : (T, 32, 3) float64, the true joints in the world frame, mm, at the frame times.
    dropped : (T, S) bool, the sensor delivered no frame at all.
    occluded : (T, S, 32) bool, ground truth, label order: the joint was self-occluded or out of view.
    times_s : (T,) nominal frame times from the start of the take, s.
    """

    sensor_ids: tuple[str, ...]
    positions: np.ndarray
    confidence: np.ndarray
    body_ids: np.ndarray
    tracked: np.ndarray
    mirrored: np.ndarray
    device_time_us: np.ndarray
    host_time_ns: np.ndarray
    world_from_sensor: np.ndarray
    world_from_sensor_calibrated: np.ndarray
    truth: np.ndarray
    dropped: np.ndarray
    occluded: np.ndarray
    times_s: np.ndarray

    @property
    def n_frames(self) -> int:
        return int(self.positions.shape[0])

    @property
    def n_sensors(self) -> int:
        return int(self.positions.shape[1])

    def positions_world(self, *, calibrated: bool) -> np.ndarray:
        """(T, S, 32, 3) float64 world positions: ``calibrated`` picks the extrinsics with the profile's calibration
        error (what a real rig fuses with) or the true ones; no default, so every caller says which."""
        poses = self.world_from_sensor_calibrated if calibrated else self.world_from_sensor
        return apply_transform(poses, self.positions.astype(np.float64))


# ----------------------------------------------------------------------------------------------------------
# Building blocks (pure functions; each is tested against its closed form)


def ar1(
    rng: np.random.Generator,
    n: int,
    shape: tuple[int, ...],
    rho: np.ndarray | float,
    sigma: np.ndarray | float,
    impulses: np.ndarray | None = None,
) -> np.ndarray:
    """Stationary AR(1) processes along axis 0: ``x[k] = rho x[k-1] + e[k]``, SD ``sigma``.

    Parameters
    ----------
    rng : random generator
    n : number of steps
    shape : shape of one step (the independent processes)
    rho, sigma : broadcastable to ``shape``
    impulses : optional (n, *shape) extra innovations added to ``e`` (jumps that then decay)

    Returns
    -------
    (n, *shape) float64. x[0] is drawn from the stationary distribution N(0, sigma²).
    """
    rho_arr = np.broadcast_to(np.asarray(rho, dtype=np.float64), shape)
    sigma_arr = np.broadcast_to(np.asarray(sigma, dtype=np.float64), shape)
    innovations = rng.standard_normal((n, *shape)) * (sigma_arr * np.sqrt(1.0 - rho_arr**2))
    innovations[0] = rng.standard_normal(shape) * sigma_arr
    if impulses is not None:
        innovations = innovations + impulses
    out = np.empty_like(innovations)
    for value in np.unique(rho_arr):  # one IIR filter per distinct coefficient (a handful of groups)
        mask = rho_arr == value
        out[:, mask] = lfilter([1.0], [1.0, -value], innovations[:, mask], axis=0)
    return out


def student_t(rng: np.random.Generator, shape: tuple[int, ...], sigma: np.ndarray | float, dof: float) -> np.ndarray:
    """Heavy-tailed white noise: Student-t with ``dof`` degrees of freedom scaled to SD ``sigma``."""
    return rng.standard_t(dof, size=shape) * (np.asarray(sigma) / np.sqrt(dof / (dof - 2.0)))


def segment_distance(p0: np.ndarray, p1: np.ndarray, q0: np.ndarray, q1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closest approach of segments [p0, p1] and [q0, q1], vectorized (broadcasting over leading axes).

    Returns
    -------
    distance : (...) the minimum distance
    s : (...) parameter in [0, 1] of the closest point on [p0, p1]

    References
    ----------
    C. Ericson, Real-Time Collision Detection (2005), 5.1.9 ClosestPtSegmentSegment.
    """
    d1, d2, r = p1 - p0, q1 - q0, p0 - q0
    d1, d2, r = np.broadcast_arrays(d1, d2, r)

    def dot(u: np.ndarray, v: np.ndarray) -> np.ndarray:
        return np.einsum("...k,...k->...", u, v)

    a, e, f, c, b = dot(d1, d1), dot(d2, d2), dot(d2, r), dot(d1, r), dot(d1, d2)
    eps = 1e-12
    a_safe = np.maximum(a, eps)
    e_safe = np.maximum(e, eps)
    denom = a * e - b * b
    s = np.where(denom > eps * np.maximum(a * e, eps), np.clip((b * f - c * e) / np.maximum(denom, eps), 0, 1), 0.0)
    t = (b * s + f) / e_safe
    s = np.where(t < 0, np.clip(-c / a_safe, 0, 1), np.where(t > 1, np.clip((b - c) / a_safe, 0, 1), s))
    t = np.clip(t, 0, 1)
    degenerate_q = e <= eps  # a sphere: closest point on p to q0
    s = np.where(degenerate_q, np.clip(-c / a_safe, 0, 1), s)
    t = np.where(degenerate_q, 0.0, t)
    # |r + s d1 - t d2|² expanded, so no (..., 3) temporaries are needed
    squared = dot(r, r) + s * s * a + t * t * e + 2 * s * c - 2 * t * f - 2 * s * t * b
    return np.sqrt(np.maximum(squared, 0.0)), s


def self_occlusion(points: np.ndarray, radii: dict[str, float], margin_mm: float) -> np.ndarray:
    """Which joints the body itself hides from a camera at the origin.

    Parameters
    ----------
    points : (T, 32, 3) true joints in the camera frame, mm
    radii : capsule radius per key of :data:`CAPSULES`, mm
    margin_mm : the occluding surface must lie at least this far in front of the joint along the ray

    Returns
    -------
    (T, 32) bool: the ray from the camera to the joint passes through a capsule that does not contain the
    joint, at a point nearer the camera than the joint by at least ``margin_mm``.
    """
    starts = points[:, [J[c[1]] for c in CAPSULES]][:, None]  # (T, 1, C, 3)
    ends = points[:, [J[c[2]] for c in CAPSULES]][:, None]
    radius = np.array([radii[c[0]] for c in CAPSULES])  # (C,)
    joints = points[:, :, None, :]  # (T, 32, 1, 3)
    origin = np.zeros_like(joints)
    ray_dist, s = segment_distance(origin, joints, starts, ends)  # (T, 32, C)
    inside, _ = segment_distance(joints, joints, starts, ends)
    depth = np.linalg.norm(joints, axis=-1)  # (T, 32, 1)
    hides = (ray_dist < radius) & (inside > radius) & (s * depth < depth - margin_mm) & _CAN_HIDE
    return hides.any(axis=-1)


def facing_away_deg(truth: np.ndarray, sensor_position: np.ndarray) -> np.ndarray:
    """(T,) angle between the body's facing and the horizontal direction to the sensor, degrees (0 = faces it)."""
    forward = root_facing(truth)
    to_sensor = sensor_position[None, :] - truth[:, J["PELVIS"]]
    to_sensor[:, 2] = 0.0
    to_sensor /= np.maximum(np.linalg.norm(to_sensor, axis=1, keepdims=True), 1e-9)
    return np.degrees(np.arccos(np.clip(np.sum(forward * to_sensor, axis=1), -1.0, 1.0)))


def mirror_bursts(
    rng: np.random.Generator, angle_deg: np.ndarray, tracked: np.ndarray, profile: SimProfile
) -> np.ndarray:
    """(T,) bool: left/right flip bursts, a Markov chain driven by the facing angle (with hysteresis)."""
    uniform = rng.random(angle_deg.size)
    away = angle_deg > profile.away_threshold_deg
    hold_from = profile.away_threshold_deg - profile.hysteresis_deg
    if profile.side_flip_prob > 0:  # failure family "side_flips": side views flip too, and hold while sideways
        hold_from = min(hold_from, profile.side_flip_min_deg)
    holdable = angle_deg > hold_from
    side = (angle_deg > profile.side_flip_min_deg) & ~away
    free = angle_deg <= profile.front_free_deg
    out = np.zeros(angle_deg.size, dtype=bool)
    state = False
    for k in range(angle_deg.size):  # scalar state machine over frames; numpy would not help here
        if not tracked[k] or free[k]:
            state = False
        elif state:
            p_off = profile.flip_off_prob_away if holdable[k] else profile.flip_off_prob_front
            state = uniform[k] >= p_off
        elif away[k]:
            state = uniform[k] < profile.flip_on_prob
        elif side[k]:
            state = uniform[k] < profile.side_flip_prob
        out[k] = state
    return out


def limb_swap_bursts(
    rng: np.random.Generator, angle_deg: np.ndarray, eligible: np.ndarray, profile: SimProfile
) -> np.ndarray:
    """(T, 2) bool: bursts in which one limb pair (column 0 the arms, 1 the legs) has its left and right labels
    swapped, in views that do not see the body from behind (failure family "limb_swaps"; the case the paper's
    per-pair realignment targets). Each starts with ``limb_swap_prob`` per frame and pair and ends with
    ``limb_swap_off_prob``."""
    n = angle_deg.size
    out = np.zeros((n, 2), dtype=bool)
    if profile.limb_swap_prob <= 0:
        return out
    uniform = rng.random((n, 2))
    allowed = eligible & (angle_deg <= profile.away_threshold_deg)
    state = np.zeros(2, dtype=bool)
    for k in range(n):  # a two-state chain per pair, vectorized over the pairs
        state = np.where(state, uniform[k] >= profile.limb_swap_off_prob, uniform[k] < profile.limb_swap_prob)
        state &= allowed[k]
        out[k] = state
    return out


def _swap_limbs(
    lab: np.ndarray, hidden: np.ndarray, in_view: np.ndarray, swaps: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Swap the left/right labels of the arm (``swaps[:, 0]``) and leg (``swaps[:, 1]``) chains where set."""
    if not swaps.any():
        return lab, hidden, in_view
    lab, hidden, in_view = lab.copy(), hidden.copy(), in_view.copy()
    for column, (left, right) in enumerate(_LIMB_CHAINS):
        frames = swaps[:, column]
        for array in (lab, hidden, in_view):
            left_values = array[frames][:, left].copy()
            array[np.ix_(frames, left)] = array[frames][:, right]
            array[np.ix_(frames, right)] = left_values
    return lab, hidden, in_view


def symmetric_bone_lengths(truth: np.ndarray) -> np.ndarray:
    """(32,) the tracker's template length of the bone ending at each joint (median over frames, left and
    right averaged: the body model is symmetric). Entry 0 (pelvis) is zero."""
    lengths = np.zeros(N_JOINTS)
    lengths[BONES[:, 1]] = np.median(np.linalg.norm(truth[:, BONES[:, 1]] - truth[:, BONES[:, 0]], axis=-1), axis=0)
    return 0.5 * (lengths + lengths[MIRROR])


_IK_CHILD = {
    J[f"{joint}_{side}"]: J[f"{child}_{side}"]
    for side in ("LEFT", "RIGHT")
    for joint, child in (("ELBOW", "WRIST"), ("WRIST", "HAND"), ("KNEE", "ANKLE"), ("ANKLE", "FOOT"))
}
"""A limb joint and the child that continues its chain: a guessed joint is placed so that this child, when the
tracker sees it, stays where it was seen (two-bone IK in :func:`fit_body_model`)."""


def fit_body_model(
    noisy: np.ndarray, bone_lengths: np.ndarray, scale: np.ndarray, guessed: np.ndarray | None = None
) -> np.ndarray:
    """Refit joints to a body model with fixed bone lengths times one size factor per frame.

    Walks the kinematic chain from the pelvis: each joint goes ``scale * length`` away from its already
    fitted parent, in the direction of its noisy position. A guessed limb joint (``guessed``: hidden or lost)
    whose chain child (:data:`_IK_CHILD`: elbow -> wrist, wrist -> hand, knee -> ankle, ankle -> foot) is
    not guessed is placed by two-bone IK instead: on the circle of positions that keep both bone lengths and
    put the child where it was seen (as near as the two bones reach), on the side of its own guess. A model
    fitter anchors a hidden elbow to the wrist it sees; walking the chain would instead carry the elbow's
    guess error, redrawn at every jump, down to the visible wrist and hand.

    Parameters
    ----------
    noisy : (T, 32, 3) joints, mm
    bone_lengths : (32,) template length of the bone ending at each joint, mm
    scale : (T,) size factor
    guessed : (T, 32) bool or None, joints the tracker guessed (None: none)

    Returns
    -------
    (T, 32, 3): every bone's length is exactly ``scale[t] * bone_lengths[j]``.
    """
    out = np.empty_like(noisy)
    out[:, 0] = noisy[:, 0]
    for joint in range(1, N_JOINTS):
        parent = PARENTS[joint]
        length = scale * bone_lengths[joint]
        direction = noisy[:, joint] - out[:, parent]
        norm = np.linalg.norm(direction, axis=1, keepdims=True)
        direction = np.where(norm > 1e-9, direction / np.maximum(norm, 1e-9), np.array([0.0, 1.0, 0.0]))
        out[:, joint] = out[:, parent] + direction * length[:, None]
        child = _IK_CHILD.get(joint)
        if guessed is not None and child is not None:
            rows = guessed[:, joint] & ~guessed[:, child]
            if rows.any():
                out[rows, joint] = _two_bone(
                    out[rows, parent],
                    noisy[rows, child],
                    out[rows, joint],
                    length[rows],
                    (scale * bone_lengths[child])[rows],
                )
    return out


def _two_bone(root: np.ndarray, target: np.ndarray, hint: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(n, 3) the middle joint of a two-bone chain ``root -(a)- middle -(b)- end`` with the end as near ``target``
    as the bones reach, on the side of ``hint`` (the plane through root, target and hint)."""
    axis = target - root
    d = np.linalg.norm(axis, axis=1)
    u = np.where(d[:, None] > 1e-9, axis / np.maximum(d, 1e-9)[:, None], np.array([0.0, 0.0, 1.0]))
    d = np.clip(d, np.abs(a - b) + 1e-6, a + b - 1e-6)
    along = (a * a - b * b + d * d) / (2.0 * d)
    radius = np.sqrt(np.maximum(a * a - along * along, 0.0))
    side = hint - root
    side = side - np.sum(side * u, axis=1, keepdims=True) * u
    norm = np.linalg.norm(side, axis=1, keepdims=True)
    other = np.cross(u, np.where(np.abs(u[:, :1]) < 0.9, np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])))
    side = np.where(norm > 1e-9, side / np.maximum(norm, 1e-9), other / np.linalg.norm(other, axis=1, keepdims=True))
    return root + along[:, None] * u + radius[:, None] * side


def _sensor_rngs(seed: int, sensor_id: str) -> dict[str, np.random.Generator]:
    """Independent streams per sensor, keyed by its id: adding a sensor leaves the others' draws alone."""
    key = zlib.crc32(sensor_id.encode("utf-8"))
    names = ("tracking", "noise", "confidence", "timing", "calibration", "scale", "failures", "loss")
    return {name: np.random.default_rng([seed, key, idx]) for idx, name in enumerate(names)}


def _default_pose(lab: np.ndarray, bone_lengths: np.ndarray, down: np.ndarray) -> np.ndarray:
    """The tracker's prior for a hidden limb joint: the limb hanging straight down from its shoulder/hip."""
    prior = lab.copy()
    for side in ("LEFT", "RIGHT"):
        for root, chain in (
            (f"SHOULDER_{side}", ("ELBOW", "WRIST", "HAND", "HANDTIP")),
            (f"HIP_{side}", ("KNEE", "ANKLE", "FOOT")),
        ):
            reach = 0.0
            for name in chain:
                reach += bone_lengths[J[f"{name}_{side}"]]
                prior[:, J[f"{name}_{side}"]] = lab[:, J[root]] + reach * down
        prior[:, J[f"THUMB_{side}"]] = prior[:, J[f"HAND_{side}"]]
    return prior


def _reflect(points: np.ndarray, centre: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Reflect (T, n, 3) points through the plane through (T, 3) centres with (T, 3) unit normals."""
    offset = points - centre[:, None]
    return points - 2.0 * np.sum(offset * normal[:, None], axis=-1, keepdims=True) * normal[:, None]


def _calibration_error(rng: np.random.Generator, profile: SimProfile) -> np.ndarray:
    """(4, 4) small rigid perturbation (rotation about a random axis, translation), sensor frame."""
    axis = rng.standard_normal(3)
    axis /= np.linalg.norm(axis)
    angle = np.radians(rng.normal(0.0, profile.calibration_rotation_sd_deg))
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    delta = np.eye(4)
    delta[:3, :3] = np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * (k @ k)
    delta[:3, 3] = rng.normal(0.0, profile.calibration_translation_sd_mm, 3)
    return delta


def _group_values(table: dict[str, float]) -> np.ndarray:
    """(32, 1) per-joint value of a per-group table, broadcastable over axes."""
    return np.array([table[g] for g in NOISE_GROUPS])[JOINT_NOISE_GROUP][:, None]


# ----------------------------------------------------------------------------------------------------------


def simulate(motion: Motion, sensors: list[VirtualSensor], profile: SimProfile, *, seed: int) -> Observations:
    """Simulate what each sensor's body tracker reports while ``motion`` happens.

    Parameters
    ----------
    motion : the ground truth (resampled to the profile's frame rate)
    sensors : the rig; index 0 is the master (exact calibration, no depth delay)
    profile : observation model parameters (:func:`load_profile`)
    seed : everything random derives from it; each sensor draws from its own streams keyed by its id

    Returns
    -------
    Observations
    """
    if not sensors:
        raise ValueError("simulate needs at least one sensor")
    ids = [s.sensor_id for s in sensors]
    if len(set(ids)) != len(ids):
        raise ValueError(f"sensor ids must be unique, got {ids}")
    motion = _posture(motion, profile)
    level_down = [-s.world_from_sensor[2, :3] for s in sensors]  # world down in each level camera's frame
    sensors = _tilted_mounts(sensors, profile, np.random.default_rng([seed, 0x7117]))
    last_s = (motion.n_frames - 1) / motion.fps
    n = int(np.floor(last_s * profile.fps + 1e-6)) + 1
    times = np.arange(n) / profile.fps
    truth = motion.at_times(times)
    n_sensors = len(sensors)
    neighbour = _neighbour(motion, times, truth, profile)
    seen = _common_mode(motion, times, truth, profile, np.random.default_rng([seed, 0xC033]))
    speed_mps = np.linalg.norm(np.gradient(truth, axis=0), axis=-1) * profile.fps / 1000.0  # (T, 32)

    bone_lengths = symmetric_bone_lengths(truth)
    pelvis_z = truth[:, J["PELVIS"], 2]
    drop_mm = np.maximum(np.percentile(pelvis_z, 90) - pelvis_z, 0.0)
    pose_scale = 1.0 - np.minimum(profile.scale_per_100mm_drop * drop_mm / 100.0, profile.scale_max_shrink)
    forward_world = root_facing(truth)

    positions = np.full((n, n_sensors, N_JOINTS, 3), np.nan, dtype=np.float32)
    confidence = np.zeros((n, n_sensors, N_JOINTS), dtype=np.uint8)
    body_ids = np.full((n, n_sensors), -1, dtype=np.int64)
    tracked_all = np.zeros((n, n_sensors), dtype=bool)
    mirrored_all = np.zeros((n, n_sensors), dtype=bool)
    dropped_all = np.zeros((n, n_sensors), dtype=bool)
    occluded_all = np.zeros((n, n_sensors, N_JOINTS), dtype=bool)
    device_time = np.zeros((n, n_sensors), dtype=np.int64)
    host_time = np.zeros((n, n_sensors), dtype=np.int64)
    poses = np.stack([s.world_from_sensor for s in sensors])
    poses_calibrated = poses.copy()

    for index, sensor in enumerate(sensors):
        rngs = _sensor_rngs(seed, sensor.sensor_id)
        rotation = sensor.world_from_sensor[:3, :3]
        physical = sensor.to_sensor(seen)  # (T, 32, 3) sensor frame (seen = truth unless a common-mode family)
        if index == 0 and neighbour is not None:  # the first sensor confuses the subject with a close neighbour
            physical = _confuse_with_neighbour(rngs["failures"], physical, sensor.to_sensor(neighbour), profile)

        # 1. visibility and tracking
        in_view = sensor.in_view(physical)
        dropped = rngs["tracking"].random(n) < profile.dropped_frame_prob
        torso_visible = in_view[:, TORSO_TRACKING_JOINTS].sum(axis=1) >= profile.min_torso_joints_in_view
        tracked = torso_visible & ~dropped
        # 2. self-occlusion (geometry of the true body)
        hidden = self_occlusion(physical, profile.capsule_radius_mm, profile.occlusion_margin_mm) | ~in_view
        # 3. mirroring and body ids
        angle = facing_away_deg(truth, sensor.position_mm)
        mirrored = mirror_bursts(rngs["tracking"], angle, tracked, profile)
        prev_tracked = np.concatenate([[False], tracked[:-1]])
        prev_mirrored = np.concatenate([[False], mirrored[:-1]])
        new_body = tracked & (~prev_tracked | (mirrored & ~prev_mirrored))
        loss_flipped, loss_away, loss_starts = tracker_loss_episodes(
            rngs["loss"],
            tracked,
            profile.tracker_loss_prob,
            profile.tracker_loss_flip_frames,
            profile.tracker_loss_away_frames,
        )
        new_body |= loss_starts
        body_ids[:, index] = np.where(tracked, np.cumsum(new_body), -1)

        # 4-7. what the tracker reports: labels, error, body-model refit, confidence, timestamps
        lab, hidden, in_view = _label_space(physical, hidden, in_view, mirrored, forward_world[mirrored] @ rotation)
        swaps = limb_swap_bursts(rngs["failures"], angle, tracked & ~mirrored, profile)
        lab, hidden, in_view = _swap_limbs(lab, hidden, in_view, swaps)
        restarts = new_body if profile.flip_restarts_fit else new_body & ~(mirrored & prev_tracked)
        lost = leg_low_episodes(rngs["confidence"], n, profile) & ~hidden
        gain = _noise_gain(lab, np.where(mirrored[:, None], speed_mps[:, MIRROR], speed_mps), profile)
        # The tracker's prior for hidden limbs hangs them along its idea of down: the level camera's (a tilted
        # mount does not tell the tracker it is tilted; without the tilt family the two are the same).
        down = level_down[index] if profile.mount_tilt_deg > 0 else -rotation[2]
        noisy = _tracker_error(rngs["noise"], lab, hidden, restarts, bone_lengths, down, profile, lost, gain)
        noisy = _partial_view_drag(noisy, lab, in_view, profile.partial_view_drag)
        fitted = _body_model(rngs["scale"], noisy, bone_lengths, pose_scale, profile, hidden | lost)
        labels = _confidence_labels(rngs["confidence"], hidden, in_view, profile, lost)
        if loss_starts.any():
            fitted = apply_tracker_loss(
                fitted, loss_flipped, loss_away, -rotation[2], profile.tracker_loss_offset_mm, rngs["loss"]
            )

        positions[tracked, index] = fitted[tracked].astype(np.float32)
        confidence[tracked, index] = labels[tracked]
        tracked_all[:, index] = tracked
        mirrored_all[:, index] = mirrored
        dropped_all[:, index] = dropped
        occluded_all[:, index] = hidden & tracked[:, None]
        device_time[:, index], host_time[:, index] = _timestamps(rngs["timing"], n, index, dropped, profile)
        if index > 0:
            poses_calibrated[index] = sensor.world_from_sensor @ _calibration_error(rngs["calibration"], profile)

    return Observations(
        sensor_ids=tuple(ids),
        positions=positions,
        confidence=confidence,
        body_ids=body_ids,
        tracked=tracked_all,
        mirrored=mirrored_all,
        device_time_us=device_time,
        host_time_ns=host_time,
        world_from_sensor=poses,
        world_from_sensor_calibrated=poses_calibrated,
        truth=truth,
        dropped=dropped_all,
        occluded=occluded_all,
        times_s=times,
    )


def _label_space(
    physical: np.ndarray, hidden: np.ndarray, in_view: np.ndarray, mirrored: np.ndarray, forward: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The true joints as the tracker labels them (stage 3 of :func:`simulate`).

    A mirrored fit faces the sensor, so face and toes go to the sensor's side (``forward``: the body's facing
    in the sensor frame, for the mirrored frames) and the left/right labels swap, with the joints' occlusion
    and visibility.
    """
    lab = physical.copy()
    if not mirrored.any():
        return lab, hidden, in_view
    m_lab = lab[mirrored]
    m_lab[:, _FACE_JOINTS] = _reflect(m_lab[:, _FACE_JOINTS], m_lab[:, J["HEAD"]], forward)
    for tip in _FOOT_TIPS:
        ankle = PARENTS[tip]
        m_lab[:, [tip]] = _reflect(m_lab[:, [tip]], m_lab[:, ankle], forward)
    lab[mirrored] = m_lab[:, MIRROR]
    hidden = np.where(mirrored[:, None], hidden[:, MIRROR], hidden)
    in_view = np.where(mirrored[:, None], in_view[:, MIRROR], in_view)
    return lab, hidden, in_view


def _tracker_error(
    noise: np.random.Generator,
    lab: np.ndarray,
    hidden: np.ndarray,
    restarts: np.ndarray,
    bone_lengths: np.ndarray,
    down: np.ndarray,
    profile: SimProfile,
    lost: np.ndarray | None = None,
    gain: np.ndarray | None = None,
) -> np.ndarray:
    """Stage 4 of :func:`simulate`: constant offsets, slow AR(1) error with jumps, heavy-tailed white jitter, the
    pull of hidden joints toward a default pose plus their guess error, and the convergence after a (re)start.

    ``restarts``: frames where the tracker starts a new fit; ``down``: world -z in the sensor frame; ``lost``:
    (n, 32) visible joints the tracker lost for a moment (leg LOW episodes): they carry the guess error too,
    without the pull; ``gain``: (n, 32) factor on the slow and white error (failure family "distance_speed").
    """
    n = lab.shape[0]
    offsets = noise.normal(0.0, 1.0, (N_JOINTS, 3)) * _group_values(profile.offset_sigma_mm)
    jumps = (noise.random((n, N_JOINTS, 1)) < profile.jump_prob) & ~hidden[:, :, None]
    impulses = jumps * noise.normal(0.0, profile.jump_sigma_mm, (n, N_JOINTS, 3))
    slow = ar1(noise, n, (N_JOINTS, 3), _group_values(profile.slow_rho), _group_values(profile.slow_sigma_mm), impulses)
    white = student_t(noise, (n, N_JOINTS, 3), _group_values(profile.white_sigma_mm), profile.white_dof)
    guess = _occluded_guess_error(noise, n, profile)
    prior = _default_pose(lab, bone_lengths, down)
    noisy = lab + offsets + (slow + white) * (1.0 if gain is None else gain[:, :, None])
    noisy = noisy + hidden[:, :, None] * (profile.occluded_pull * (prior - lab) + guess)
    if lost is not None:
        noisy = noisy + lost[:, :, None] * guess
    if profile.convergence_frames > 0:
        run_start = np.maximum.accumulate(np.where(restarts, np.arange(n), 0))
        since = np.arange(n) - run_start
        initial = noise.normal(0.0, profile.convergence_sigma_mm, (N_JOINTS, 3))
        noisy = noisy + np.exp(-since / profile.convergence_frames)[:, None, None] * initial
    return noisy


def _body_model(
    scale_rng: np.random.Generator,
    noisy: np.ndarray,
    bone_lengths: np.ndarray,
    pose_scale: np.ndarray,
    profile: SimProfile,
    guessed: np.ndarray | None = None,
) -> np.ndarray:
    """Stage 5 of :func:`simulate`: refit the noisy joints to the body model with one size factor per frame
    (a per-view level, the pose's shrink, a slow drift); ``guessed`` joints are fitted around what is seen."""
    level = 1.0 + np.clip(scale_rng.normal(0.0, profile.scale_view_sd), -profile.scale_view_max, profile.scale_view_max)
    drift = ar1(scale_rng, noisy.shape[0], (), profile.scale_slow_rho, profile.scale_slow_sd)
    return fit_body_model(noisy, bone_lengths, level * pose_scale * (1.0 + drift), guessed)


def leg_low_episodes(rng: np.random.Generator, n: int, profile: SimProfile) -> np.ndarray:
    """(n, 32) bool: short episodes in which the tracker loses a leg (its knee, ankle and foot) although it is
    in view: each starts with ``leg_low_prob`` per frame and leg and lasts ``floor(U ** (-1 / alpha))`` frames
    (at most ``leg_low_max_frames``), a heavy tail: real episodes last a median 1 frame, the longest 6-15."""
    starts = rng.random((n, 2)) < profile.leg_low_prob
    lengths = np.minimum(
        np.floor((1.0 - rng.random((n, 2))) ** (-1.0 / profile.leg_low_length_alpha)), profile.leg_low_max_frames
    ).astype(np.int64)
    remaining = np.zeros(2, dtype=np.int64)
    legs = np.zeros((n, 2), dtype=bool)
    for k in range(n):  # a countdown per leg, vectorized over the legs
        remaining = np.where(starts[k], np.maximum(remaining, lengths[k]), remaining)
        legs[k] = remaining > 0
        remaining = np.maximum(remaining - 1, 0)
    out = np.zeros((n, N_JOINTS), dtype=bool)
    for side, leg in enumerate(_LEG_CHAINS):
        out[:, leg] = legs[:, side : side + 1]
    return out


def _confidence_labels(
    conf_rng: np.random.Generator,
    hidden: np.ndarray,
    in_view: np.ndarray,
    profile: SimProfile,
    lost: np.ndarray | None = None,
) -> np.ndarray:
    """Stage 6 of :func:`simulate`: (n, 32) confidence: MEDIUM, LOW for hidden limb joints and lost legs (torso
    joints rarely: the tracker sees the trunk around a limb), NONE for whole-hand episodes and out of view."""
    n = hidden.shape[0]
    labels = np.full((n, N_JOINTS), Confidence.MEDIUM, dtype=np.uint8)
    if lost is not None:
        labels[lost] = Confidence.LOW
    low_prob = np.where(_TORSO_JOINTS_MASK, profile.torso_occluded_low_prob, profile.occluded_low_prob)
    hidden_low = hidden & (conf_rng.random((n, N_JOINTS)) < low_prob)
    labels[hidden_low] = Confidence.LOW
    fraction = conf_rng.uniform(profile.hand_none_fraction_min, profile.hand_none_fraction_max, len(_HAND_SIDES))
    latent = ar1(conf_rng, n, (len(_HAND_SIDES),), profile.hand_none_rho, 1.0)
    hand_none = latent < ndtri(np.clip(fraction, 1e-9, 1 - 1e-9))  # (n, 2): the tracker drops a whole hand
    for side, joints in enumerate(_HAND_SIDES):
        labels[np.ix_(hand_none[:, side], joints)] = Confidence.NONE
    labels[~in_view] = Confidence.NONE
    return labels


def _timestamps(
    timing: np.random.Generator, n: int, index: int, dropped: np.ndarray, profile: SimProfile
) -> tuple[np.ndarray, np.ndarray]:
    """Stage 7 of :func:`simulate`: device timestamps (µs; subordinates after the master by their delay) and host
    timestamps (ns; latency and a per-host offset, never running backwards); -1 for dropped frames."""
    period_us = 1e6 / profile.fps
    device = (
        profile.device_time_start_us
        + np.arange(n) * period_us
        + timing.normal(0.0, profile.frame_interval_jitter_us / np.sqrt(2.0), n)
    )
    if index > 0:
        device = (
            device + index * profile.subordinate_delay_us - timing.uniform(0.0, profile.subordinate_delay_spread_us, n)
        )
    latency_ms = np.maximum(
        profile.host_latency_mean_ms
        + timing.normal(0.0, profile.host_offset_sd_ms)
        + timing.normal(0.0, profile.host_latency_jitter_ms, n),
        0.0,
    )
    host = profile.host_epoch_s * 1e9 + device * 1e3 + latency_ms * 1e6
    host = np.maximum.accumulate(host)  # a host clock never runs backwards
    return np.where(dropped, -1, np.rint(device).astype(np.int64)), np.where(
        dropped, -1, np.rint(host).astype(np.int64)
    )


def _posture(motion: Motion, profile: SimProfile) -> Motion:
    """The motion as the subject performs it sitting or lying (families "sitting", "lying"); unchanged otherwise.

    Sitting: per frame each thigh points level along the body's facing from its hip, the shin straight down, the
    foot forward (every bone keeps its length), and the whole body is lowered until the lower ankle is at the
    height the standing ankles had (on a chair, feet on the floor). Lying: the whole body turned 90 degrees
    about the lateral axis through the pelvis (head away from the facing, face up) and lowered until the pelvis
    is 120 mm above the floor (on the back).
    """
    if not (profile.sitting or profile.lying):
        return motion
    pos = motion.positions.astype(np.float64).copy()
    forward = root_facing(pos)  # (T, 3) horizontal
    if profile.sitting:
        ankle_floor = np.min(pos[:, [J["ANKLE_LEFT"], J["ANKLE_RIGHT"]], 2])
        down = np.array([0.0, 0.0, -1.0])
        for side in ("LEFT", "RIGHT"):
            hip, knee, ankle, foot = (J[f"{name}_{side}"] for name in ("HIP", "KNEE", "ANKLE", "FOOT"))
            thigh = np.linalg.norm(pos[:, knee] - pos[:, hip], axis=1, keepdims=True)
            shin = np.linalg.norm(pos[:, ankle] - pos[:, knee], axis=1, keepdims=True)
            sole = np.linalg.norm(pos[:, foot] - pos[:, ankle], axis=1, keepdims=True)
            pos[:, knee] = pos[:, hip] + thigh * forward
            pos[:, ankle] = pos[:, knee] + shin * down
            pos[:, foot] = pos[:, ankle] + sole * forward
        lowest = np.min(pos[:, [J["ANKLE_LEFT"], J["ANKLE_RIGHT"]], 2], axis=1)
        pos[:, :, 2] -= (lowest - ankle_floor)[:, None]
    else:
        axis = np.cross(forward, np.array([0.0, 0.0, 1.0]))  # lateral: turns up into -forward, forward into up
        pelvis = pos[:, J["PELVIS"]][:, None]
        offset = pos - pelvis
        cross = np.cross(axis[:, None], offset)
        along = np.sum(axis[:, None] * offset, axis=-1, keepdims=True) * axis[:, None]
        pos = pelvis + cross + along  # Rodrigues at 90 degrees: v' = a x v + a (a . v)
        pos[:, :, 2] += 120.0 - pos[:, J["PELVIS"], 2][:, None]
    return Motion(motion.name, motion.fps, pos)


def _tilted_mounts(sensors: list[VirtualSensor], profile: SimProfile, rng: np.random.Generator) -> list[VirtualSensor]:
    """Every sensor rolled about its optical axis and pitched about its x axis by angles drawn uniformly in
    +-``mount_tilt_deg`` (family "tilted_mounts"): the true poses; the rig's calibration measures them (as a rig
    calibrated where it stands), but the body tracker keeps assuming a level camera (see :func:`simulate`)."""
    if profile.mount_tilt_deg <= 0:
        return sensors
    out = []
    for sensor in sensors:
        roll, pitch = np.radians(rng.uniform(-profile.mount_tilt_deg, profile.mount_tilt_deg, 2))
        tilt = np.eye(4)
        tilt[:3, :3] = _rotation_z(roll) @ _rotation_x(pitch)
        out.append(dataclasses.replace(sensor, world_from_sensor=sensor.world_from_sensor @ tilt))
    return out


def _rotation_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _rotation_x(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _neighbour(motion: Motion, times: np.ndarray, truth: np.ndarray, profile: SimProfile) -> np.ndarray | None:
    """(T, 32, 3) world joints of a second person beside the subject (family "close_people"): the same motion
    one second behind, ``neighbour_distance_mm`` to the subject's right. None when the family is off."""
    if profile.neighbour_distance_mm <= 0 or (profile.neighbour_swap_prob <= 0 and profile.neighbour_merge_prob <= 0):
        return None
    forward = root_facing(truth)
    right = np.stack([forward[:, 1], -forward[:, 0], np.zeros(len(times))], axis=1)
    behind = motion.at_times(np.maximum(times - 1.0, 0.0))
    return behind + profile.neighbour_distance_mm * right[:, None]


def _confuse_with_neighbour(
    rng: np.random.Generator, physical: np.ndarray, neighbour: np.ndarray, profile: SimProfile
) -> np.ndarray:
    """The subject's joints as a view that confuses the subject with the neighbour reports them: in swap bursts
    the neighbour's joints (ids swapped), in merge bursts the midpoint of both (one skeleton for two people).
    Bursts start with ``neighbour_swap_prob`` / ``neighbour_merge_prob`` per frame, end with
    ``neighbour_off_prob``."""
    n = physical.shape[0]
    uniform = rng.random((n, 2))
    state = np.zeros(n, dtype=np.int8)  # 0 none, 1 swapped, 2 merged
    current = 0
    for k in range(n):  # a three-state chain over frames
        if current:
            current = 0 if uniform[k, 0] < profile.neighbour_off_prob else current
        elif uniform[k, 0] < profile.neighbour_swap_prob:
            current = 1
        elif uniform[k, 1] < profile.neighbour_merge_prob:
            current = 2
        state[k] = current
    out = np.where((state == 1)[:, None, None], neighbour, physical)
    return np.where((state == 2)[:, None, None], 0.5 * (physical + neighbour), out)


def _partial_view_drag(noisy: np.ndarray, lab: np.ndarray, in_view: np.ndarray, drag: float) -> np.ndarray:
    """A body partly outside the view: the fit to the visible part is dragged by the guessed part. Every in-view
    joint moves by ``drag`` times the mean error of the out-of-view joints of its frame (failure family
    "partial_view"); frames with the whole body in view are left alone."""
    if drag <= 0:
        return noisy
    outside = ~in_view
    count = outside.sum(axis=1)
    partly = (count > 0) & (count < N_JOINTS)
    if not partly.any():
        return noisy
    error = np.where(outside[:, :, None], noisy - lab, 0.0).sum(axis=1) / np.maximum(count, 1)[:, None]
    shift = drag * error[:, None, :] * (partly[:, None] & in_view)[:, :, None]
    return noisy + shift


def _noise_gain(lab: np.ndarray, speed_mps: np.ndarray, profile: SimProfile) -> np.ndarray | None:
    """(n, 32) factor on a view's slow and white error: 1 + noise_gain_per_m per metre of depth beyond 2 m +
    noise_gain_per_mps per m/s of the joint's speed (None when both gains are off)."""
    if profile.noise_gain_per_m == 0 and profile.noise_gain_per_mps == 0:
        return None
    beyond_m = np.maximum(lab[..., 2] / 1000.0 - 2.0, 0.0)
    return 1.0 + profile.noise_gain_per_m * beyond_m + profile.noise_gain_per_mps * speed_mps


def _common_mode(
    motion: Motion, times: np.ndarray, truth: np.ndarray, profile: SimProfile, rng: np.random.Generator
) -> np.ndarray:
    """(T, 32, 3) world joints as every tracker sees them: the truth, late by ``lag_frames`` and with a body-model
    error shared by all views (a constant plus a slow AR(1) per joint and axis), which averaging views cannot
    remove. The truth itself when the failure families that set these are off."""
    seen = truth
    if profile.lag_frames > 0:
        seen = motion.at_times(np.maximum(times - profile.lag_frames / profile.fps, 0.0))
    if profile.common_offset_sigma_mm > 0 or profile.common_slow_sigma_mm > 0:
        n = truth.shape[0]
        offset = rng.normal(0.0, profile.common_offset_sigma_mm, (N_JOINTS, 3))
        slow = ar1(rng, n, (N_JOINTS, 3), _group_values(profile.slow_rho), profile.common_slow_sigma_mm)
        seen = seen + offset + slow
    return seen


def _occluded_guess_error(rng: np.random.Generator, n: int, profile: SimProfile) -> np.ndarray:
    """(n, 32, 3) the tracker's guess error for hidden joints: AR(1) that is redrawn on jumps."""
    sigma = _group_values(profile.occluded_sigma_mm)
    rho = profile.occluded_rho
    draws = rng.standard_normal((n, N_JOINTS, 3)) * sigma
    redraw = rng.random((n, N_JOINTS, 1)) < profile.occluded_jump_prob
    innovation = draws * np.sqrt(1.0 - rho**2)
    out = np.empty((n, N_JOINTS, 3))
    state = draws[0]
    for k in range(n):  # recursion over frames, vectorized over joints and axes
        state = np.where(redraw[k], draws[k], rho * state + innovation[k]) if k else state
        out[k] = state
    return out
