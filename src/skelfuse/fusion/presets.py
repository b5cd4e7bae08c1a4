"""Fusion parameters, the paper's ablation presets A1-A5 (Lee et al. 2022, section 3.1) and ours.

One frozen :class:`FusionParams` holds every option of the fusion core. Units are in the names, ``None``
switches a stage or a trick off (never ``-1``). :func:`preset` builds the paper's ablations and our
default, "skelfuse":

========  =========  ===============  ==============================  ==============  ==================
name      realign    merge            reference candidate (trick 1)   previous (t.2)  filter
========  =========  ===============  ==============================  ==============  ==================
A1        off        average          -                               -               off
A2        paper      average          -                               -               off
A3        paper      dbscan 100 mm    weight 2.0                      off             off
A4        paper      dbscan 100 mm    weight 2.0                      weight 1.0      off
A5        paper      dbscan 100 mm    weight 2.0                      weight 1.0      paper_kalman
skelfuse  temporal   dbscan 75 mm     off                             weight 1.0      cv_kalman 5000/15
========  =========  ===============  ==============================  ==============  ==================

"skelfuse" was chosen by ``scripts/tune_fusion.py`` on the simulator (a training seed, checked on a held-out
one): temporal realignment (recovery after 10 frames at a 3/4 evidence majority) removes the rear views'
mirroring, the error that dominates A1-A5; a 75 mm radius is as accurate as the best with less jitter; the
reference candidate adds nothing once the labels are right (and costs a reference per frame), so it is off;
cv_kalman (accel sigma 5000 mm/s^2, measurement sigma 15 mm, R divided by the number of agreeing views)
removes most of the jitter at almost no lag, where the paper's Kalman lags by frames (docs/evidence.md,
"Accuracy against the paper"). The filter's prediction as the previous candidate does no better than the
merged position, so trick 2 stays the paper's. A body that moves faster than 6 m/s (a looped take's
seam) starts its realignment cold (``max_body_speed_mm_s``). "skelfuse" also outputs fused joint orientations and a
per-joint position uncertainty (``orientations``, ``position_std``); they do not change the positions.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Literal

from skelfuse.schema.skeleton import Confidence

RealignMode = Literal["paper", "body", "temporal"]
MergeMode = Literal["dbscan", "average"]
FilterKind = Literal["paper_kalman", "cv_kalman", "alpha_beta"]
PreviousCandidate = Literal["merged", "predicted"]
KalmanOutput = Literal["predicted", "posterior"]

REALIGN_MODES: tuple[str, ...] = ("paper", "body", "temporal")
MERGE_MODES: tuple[str, ...] = ("dbscan", "average")
FILTER_KINDS: tuple[str, ...] = ("paper_kalman", "cv_kalman", "alpha_beta")
PAPER_PRESETS: tuple[str, ...] = ("A1", "A2", "A3", "A4", "A5")
ALL_PRESETS: tuple[str, ...] = (*PAPER_PRESETS, "skelfuse")
COMPARED_PRESETS: tuple[str, ...] = ("skelfuse", "A5", "A1")
"""What a report on a real take compares unless told otherwise (``skelfuse eval real``)."""


@dataclass(frozen=True)
class FusionParams:
    """Every option of :func:`skelfuse.fusion.pipeline.fuse`, validated on construction.

    Attributes
    ----------
    min_confidence : int or None
        Candidates whose tracker confidence is below this are treated as missing. Default LOW: joints the
        SDK marks NONE (out of range) carry a guessed position that would only add outliers. None keeps
        every finite candidate.
    realign : {"paper", "body", "temporal"} or None
        Left/right realignment. "paper": per pair and per sensor, section 2.2.1. "body": one flip decision
        per sensor for the whole skeleton from the summed cost over all pairs (a tracker flip mirrors the
        whole body). "temporal": the "body" decision against the previous merged skeleton of the body, with
        the initialization and recovery policy of :mod:`skelfuse.fusion.realign`. None: off.
    realign_passes : int
        "body" only: how many times the flip decision is taken, each time against a reference recomputed
        from the previous pass's realigned candidates (a mirrored view contaminates the first reference).
    recovery_frames : int
        "temporal" only: frames in a row a clear majority of views must disagree with the anchor before the
        body follows the majority (see :func:`skelfuse.fusion.realign.realign_temporal`).
    recovery_credit_frames : int
        "temporal" only: the most credit a body's anchor banks, one frame per frame in which every view agreed
        with it (at least two views, and every view that has seen the body since its cold start); a run of
        disagreement spends it before the recovery rule counts, and the rear-view rule waits as many frames
        more as it holds, at most ``recovery_frames``. 0: no credit. Default 30 (1 s at 30 fps):
        after a second in which every view agreed, views mirrored together (a person side-on between two
        facing sensors) keep a right anchor for up to ``30 + recovery_frames - 1`` frames; the price is that
        a wrong start every view vouched for (all mirrored) is undone up to 30 frames later.
    recovery_share : float
        "temporal" only: the share of the MEDIUM evidence, in (0.5, 1], that is a clear majority.
    majority_recovery_frames : int or None
        "temporal" only: frames in a row more than half of the evidence must disagree with the anchor before
        the body follows it: a slow rule that undoes a wrong start in a 2-against-2 split. Off (None) by
        default: wherever rear views outnumber front ones (three sensors, one in front) the mirrored views
        ARE the majority, and the rule would overturn correct anchors (``skelfuse eval paper``'s rear-mirroring
        scenario with 3 sensors shows it). Wrong starts from too few views are undone by the restart rule
        instead (see :func:`skelfuse.fusion.realign.realign_temporal`).
    max_body_speed_mm_s : float or None
        "temporal" only: a body whose centre (shoulders and hips) moved faster than this since the last frame
        starts its realignment cold instead of deciding against an anchor of another pose (the teleport rule
        of :func:`skelfuse.fusion.realign.realign_temporal`; a looped take's seam, a track handed to someone
        else). None: off. "skelfuse": 6000 mm/s (200 mm per frame at 30 fps; sprinters peak near 10 m/s,
        people walking in a capture space do not exceed about 2-3 m/s).
    rear_view_cos : float or None
        "temporal" only, and only where the caller passes the sensors' positions (``fuse(sensor_positions=)``):
        a view whose own skeleton faces away from its sensor, cosine of the angle between its facing and the
        direction to the sensor below this, is a rear view that is not mirrored (a mirrored rear view faces its
        sensor), so its left/right decides a cold start and disproves a mirrored anchor (the rear-view rule of
        :func:`skelfuse.fusion.realign.realign_temporal`). None: off. "skelfuse": -0.7 (facing more than
        134 deg away; on the simulator no mirrored view crosses -0.5 without a failure family that mirrors
        side views).
    rear_view_frames : int
        "temporal" only: frames in a row such rear views must disagree with the anchor before the body follows
        them (>= 1). "skelfuse": 3.
    merge : {"dbscan", "average"}
        "dbscan": per-joint clustering with Nc = 1 and winner-takes-all (section 2.2.2). "average": plain
        mean of the valid sensor candidates (the paper's A1/A2).
    eps_mm : float
        DBSCAN searching radius, mm. Two candidates closer than or exactly eps are neighbours.
    reference_weight : float or None
        Trick 1: weight of the reference candidate (mean of the best-confidence candidates) in the cluster
        score. None: no reference candidate.
    previous_weight : float or None
        Trick 2: weight of the previous frame's merged position as a candidate. None: off.
    previous_candidate : {"merged", "predicted"}
        What trick 2 (and the "temporal" anchor) uses as the previous position. "merged": last frame's merged
        position (paper). "predicted": with a "cv_kalman" or "alpha_beta" filter, the filter's one-step
        prediction ``x + v dt`` for joints with a live track (a fast limb moves 30-60 mm per frame, a
        sizeable part of eps), the merged position elsewhere; without such a filter the same as "merged".
    filter : {"paper_kalman", "cv_kalman", "alpha_beta"} or None
        Temporal filter per joint. None: the merged position is the output.
    max_coast_frames : int
        How many consecutive frames without a measurement a filtered joint is predicted for; after that it
        is output as NaN and its track reset. 0: no coasting.
    kalman_q_mm2 : float
        "paper_kalman" process noise variance per axis and frame, mm^2 (paper: 0.01).
    kalman_r_mm2 : float
        "paper_kalman" measurement noise variance per axis, mm^2 (paper: 1.0).
    kalman_p0_mm2 : float
        "paper_kalman" initial state variance per axis, mm^2 (the paper does not say; filterpy's default 1).
    kalman_output : {"predicted", "posterior"}
        "paper_kalman" output: "predicted", the paper's literal eq. 9 (``x~_t = x^_{t-1}``, one frame behind the
        measurement it has); "posterior", the filtered state after this frame's update (the fairer reading).
    cv_accel_sigma_mm_s2 : float
        "cv_kalman" white-noise acceleration standard deviation, mm/s^2 (discrete white noise model).
    cv_meas_sigma_mm : float
        "cv_kalman" measurement standard deviation per axis, mm.
    cv_velocity0_sigma_mm_s : float
        "cv_kalman" initial velocity standard deviation, mm/s (the velocity starts at 0).
    cv_scale_r_by_agree : bool
        "cv_kalman": divide R by the number of agreeing sensors (n independent views average down).
    alpha, beta : float
        "alpha_beta" gains of Algorithm 1 in Carraro et al. Default beta = alpha^2 / (2 - alpha), the
        Benedict-Bordner relation that balances noise reduction against manoeuvre tracking.
    orientations : bool
        Fuse joint orientations too (:mod:`skelfuse.fusion.orientation`): swing from the fused bones, twist
        from the views' quaternions that agree, an alpha-beta rotation filter. Off in the paper's presets.
    orientation_agree_deg : float
        Views whose swung orientations are further apart than this (deg) do not agree (outliers are dropped).
    orientation_alpha, orientation_beta : float
        Gains of the rotation filter (beta default: Benedict-Bordner, as for ``alpha``/``beta``).
    position_std : bool
        Output a per-joint one-sigma position uncertainty (mm, per axis) from the spread of the merged
        cluster and a constant-velocity covariance recursion fed with it (see
        :func:`skelfuse.fusion.pipeline.uncertainty_step`). Off in the paper's presets.
    plausibility_gate_mm : float or None
        Plausibility before merging (:mod:`skelfuse.fusion.plausibility`): a view whose torso lies farther
        than this from the track's prediction is held out. None: the whole stage is off (the paper's presets).
        "skelfuse": 250 mm (a person's torso does not leave its constant-velocity prediction by a quarter of a
        metre in one frame; the real glitch it is made for jumped about 350 mm).
    plausibility_up_cos : float
        A view whose pelvis-to-neck direction makes an angle with the track's whose cosine is below this is
        upside down. Default 0.0 (more than 90 deg off the track in one frame).
    plausibility_bone_ratio : float
        A view whose median bone length differs from the person's learned lengths by more than this share is
        another body. Default 0.3 (the tracker's scale varies 2-5 % per frame, up to 11 % in a deep squat, and
        differs between views by up to 5 %).
    plausibility_joint_speed_mm_s : float or None
        A single candidate farther than this times dt plus the gate from its own prediction is dropped. Default
        None (off): on the simulator's looped takes (a seam where the body turns round in one frame) it dropped
        14-20 joints of every view for several frames and raised the live path's error by up to 3 mm; the view
        checks catch the failures it was meant for.
    plausibility_release_frames : int
        Plausible frames in a row before a held-out view is used again (hysteresis). Default 3.
    plausibility_follow_frames : int
        Frames in a row in which every present view fails before the track follows the views (its filter
        restarts at them). Default 8 (0.27 s at 30 fps; a tracker's flip lasts about 0.1 s).
    """

    min_confidence: int | None = int(Confidence.LOW)
    realign: RealignMode | None = "paper"
    realign_passes: int = 2
    recovery_frames: int = 10
    recovery_credit_frames: int = 30
    recovery_share: float = 0.75
    majority_recovery_frames: int | None = None
    max_body_speed_mm_s: float | None = None
    rear_view_cos: float | None = None
    rear_view_frames: int = 3
    merge: MergeMode = "dbscan"
    eps_mm: float = 100.0
    reference_weight: float | None = 2.0
    previous_weight: float | None = 1.0
    previous_candidate: PreviousCandidate = "merged"
    filter: FilterKind | None = "paper_kalman"
    max_coast_frames: int = 15
    kalman_q_mm2: float = 0.01
    kalman_r_mm2: float = 1.0
    kalman_p0_mm2: float = 1.0
    kalman_output: KalmanOutput = "predicted"
    cv_accel_sigma_mm_s2: float = 5000.0
    cv_meas_sigma_mm: float = 15.0
    cv_velocity0_sigma_mm_s: float = 500.0
    cv_scale_r_by_agree: bool = True
    alpha: float = 0.5
    beta: float = 0.5**2 / (2.0 - 0.5)
    orientations: bool = False
    orientation_agree_deg: float = 45.0
    orientation_alpha: float = 0.5
    orientation_beta: float = 0.5**2 / (2.0 - 0.5)
    position_std: bool = False
    plausibility_gate_mm: float | None = None
    plausibility_up_cos: float = 0.0
    plausibility_bone_ratio: float = 0.3
    plausibility_joint_speed_mm_s: float | None = None
    plausibility_release_frames: int = 3
    plausibility_follow_frames: int = 8

    def __post_init__(self) -> None:
        if self.min_confidence is not None and not 0 <= int(self.min_confidence) <= int(Confidence.HIGH):
            raise ValueError(f"FusionParams.min_confidence must be None or 0..3, got {self.min_confidence!r}")
        _one_of("realign", self.realign, (*REALIGN_MODES, None))
        _one_of("merge", self.merge, MERGE_MODES)
        _one_of("filter", self.filter, (*FILTER_KINDS, None))
        _one_of("previous_candidate", self.previous_candidate, ("merged", "predicted"))
        _one_of("kalman_output", self.kalman_output, ("predicted", "posterior"))
        if int(self.recovery_frames) < 1:
            raise ValueError(f"FusionParams.recovery_frames must be >= 1, got {self.recovery_frames!r}")
        if int(self.recovery_credit_frames) < 0:
            raise ValueError(f"FusionParams.recovery_credit_frames must be >= 0, got {self.recovery_credit_frames!r}")
        if self.majority_recovery_frames is not None and int(self.majority_recovery_frames) < 1:
            raise ValueError(
                f"FusionParams.majority_recovery_frames must be None or >= 1, got {self.majority_recovery_frames!r}"
            )
        if int(self.rear_view_frames) < 1:
            raise ValueError(f"FusionParams.rear_view_frames must be >= 1, got {self.rear_view_frames!r}")
        if self.rear_view_cos is not None and not -1.0 <= float(self.rear_view_cos) < 0.0:
            raise ValueError(
                f"FusionParams.rear_view_cos must be None or in [-1, 0) (facing away), got {self.rear_view_cos!r}"
            )
        if not 0.5 < float(self.recovery_share) <= 1.0:
            raise ValueError(f"FusionParams.recovery_share must be in (0.5, 1], got {self.recovery_share!r}")
        if int(self.realign_passes) < 1:
            raise ValueError(f"FusionParams.realign_passes must be >= 1, got {self.realign_passes!r}")
        if not -1.0 <= float(self.plausibility_up_cos) < 1.0:
            raise ValueError(f"FusionParams.plausibility_up_cos must be in [-1, 1), got {self.plausibility_up_cos!r}")
        for name in ("plausibility_release_frames", "plausibility_follow_frames"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"FusionParams.{name} must be >= 1, got {getattr(self, name)!r}")
        if int(self.max_coast_frames) < 0:
            raise ValueError(f"FusionParams.max_coast_frames must be >= 0, got {self.max_coast_frames!r}")
        positive = [
            "eps_mm",
            "kalman_q_mm2",
            "kalman_r_mm2",
            "kalman_p0_mm2",
            "cv_accel_sigma_mm_s2",
            "cv_meas_sigma_mm",
            "cv_velocity0_sigma_mm_s",
            "plausibility_bone_ratio",
        ]
        optional_positive = [
            "reference_weight",
            "previous_weight",
            "max_body_speed_mm_s",
            "plausibility_gate_mm",
            "plausibility_joint_speed_mm_s",
        ]
        for name in positive + optional_positive:
            value = getattr(self, name)
            if value is None and name in optional_positive:
                continue
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ValueError(f"FusionParams.{name} must be a finite number > 0, got {value!r}")
        if not (0.0 < self.alpha <= 1.0 and 0.0 <= self.beta < 2.0):
            raise ValueError(f"FusionParams alpha must be in (0, 1] and beta in [0, 2), got {self.alpha}, {self.beta}")
        if not 0.0 < float(self.orientation_agree_deg) <= 180.0:
            raise ValueError(
                f"FusionParams.orientation_agree_deg must be in (0, 180], got {self.orientation_agree_deg!r}"
            )
        if not (0.0 < self.orientation_alpha <= 1.0 and 0.0 <= self.orientation_beta < 2.0):
            raise ValueError(
                "FusionParams orientation_alpha must be in (0, 1] and orientation_beta in [0, 2), got "
                f"{self.orientation_alpha}, {self.orientation_beta}"
            )


def _one_of(name: str, value: object, allowed: tuple[object, ...]) -> None:
    if value not in allowed:
        raise ValueError(f"FusionParams.{name} must be one of {allowed!r}, got {value!r}")


_PRESETS: dict[str, FusionParams] = {
    "A1": FusionParams(realign=None, merge="average", reference_weight=None, previous_weight=None, filter=None),
    "A2": FusionParams(realign="paper", merge="average", reference_weight=None, previous_weight=None, filter=None),
    "A3": FusionParams(realign="paper", merge="dbscan", reference_weight=2.0, previous_weight=None, filter=None),
    "A4": FusionParams(realign="paper", merge="dbscan", reference_weight=2.0, previous_weight=1.0, filter=None),
    "A5": FusionParams(
        realign="paper", merge="dbscan", reference_weight=2.0, previous_weight=1.0, filter="paper_kalman"
    ),
    "SKELFUSE": FusionParams(
        realign="temporal",
        max_body_speed_mm_s=6000.0,
        rear_view_cos=-0.7,
        merge="dbscan",
        eps_mm=75.0,
        reference_weight=None,
        previous_weight=1.0,
        filter="cv_kalman",
        max_coast_frames=5,
        cv_accel_sigma_mm_s2=5000.0,
        cv_meas_sigma_mm=15.0,
        cv_scale_r_by_agree=True,
        orientations=True,
        position_std=True,
        plausibility_gate_mm=250.0,
    ),
}


def preset(name: str, eps_mm: float | None = None) -> FusionParams:
    """The parameters of preset ``name``: the paper's ablations "A1".."A5" or our default "skelfuse".

    ``eps_mm`` overrides the DBSCAN radius (used by A3-A5 and "skelfuse"); None keeps the preset's own
    (100 mm for the paper's presets, the paper's best; 75 mm for "skelfuse", tuned on the simulator by
    ``scripts/tune_fusion.py``).

    Raises
    ------
    ValueError
        If ``name`` is not one of :data:`ALL_PRESETS`.
    """
    key = str(name).strip().upper()
    if key not in _PRESETS:
        raise ValueError(f"unknown fusion preset {name!r}; expected one of {', '.join(ALL_PRESETS)}")
    if eps_mm is None:
        return _PRESETS[key]
    return replace(_PRESETS[key], eps_mm=float(eps_mm))
