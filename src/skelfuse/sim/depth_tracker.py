"""A simulated stand-in for the body tracker on a person's virtual depth image (sim rigs only).

**This is not the Azure Kinect Body Tracking SDK** and its output says nothing about what the SDK would find
on a virtual image. It exists so that the depth and hybrid modes run end to end on a simulated rig where no
SDK is installed, with every stage in front of the tracker (clouds on the wire, association, merge,
frontalization, the virtual camera, the render, the inverse warp) doing its real work. The node's start-up log
names it (``[depth] tracker = "simulated"``); the config refuses it on a rig with any non-simulated sensor.

How it "tracks": a skeleton prior (the person's current skeleton estimate, which a real tracker would carry
over from its previous frame) is moved into the virtual camera frame; each joint whose pixel (and its
neighbours) shows the body surface is slid along its viewing ray to the depth the virtual image shows there
plus the simulator's body half-thickness at that joint (the radius of the widest capsule of
:data:`skelfuse.sim.depth.BODY_CAPSULES` that ends at it, scaled by shoulder width as the simulator scales it).
A joint whose surface lies more than :data:`OCCLUDED_MM` off the prior (another limb in front of it) keeps the
prior with LOW confidence; a joint outside the silhouette is not reported (NaN, NONE). Joints without a capsule
of their own (eyes, ears, clavicles, thumbs, the navel) keep the prior's depth. So it corrects the prior only
along the virtual camera's viewing rays, from the image: a check of the geometry and the plumbing, nothing more.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from skelfuse.fusion.transform import invert_transform, transform_points
from skelfuse.schema.skeleton import N_JOINTS, Confidence, joint_index
from skelfuse.sim.depth import _REFERENCE_SHOULDER_WIDTH_MM, BODY_CAPSULES

if TYPE_CHECKING:  # the simulator never runs the product's depth fusion: it only reads the view it is given
    from skelfuse.fusion.depth.pipeline import PersonDepthView

OCCLUDED_MM = 150.0
"""A surface farther than this from the prior's depth belongs to something else (an occluder, the background
of a hole-filled rim): the joint keeps the prior's depth, LOW confidence."""
WINDOW_PX = 2
"""Half-size of the pixel window whose median surface depth a joint is slid to."""


def _joint_radii() -> np.ndarray:
    radii = np.full(N_JOINTS, np.nan)
    for a, b, radius in BODY_CAPSULES:
        for name in (a, b):
            j = joint_index(name)
            radii[j] = radius if np.isnan(radii[j]) else max(radii[j], radius)
    return radii


JOINT_RADIUS_MM = _joint_radii()
"""(32,) the simulator body's half-thickness at each joint for a 1.75 m adult, NaN where no capsule ends."""
_SHOULDERS = (joint_index("SHOULDER_LEFT"), joint_index("SHOULDER_RIGHT"))


class SimulatedDepthTracker:
    """The simulated stand-in tracker (see the module docstring). Stateless across people, so one serves all."""

    name = "simulated"
    description = (
        "simulated stand-in (sim rigs only; NOT the Body Tracking SDK: a skeleton prior slid along the virtual "
        "camera's rays onto the virtual depth image)"
    )

    def track(
        self, person: int, view: PersonDepthView, prior_world: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """World (32, 3) joints and (32,) uint8 confidence for one person's virtual image; None without a prior."""
        if prior_world is None or not np.isfinite(prior_world).any():
            return None
        camera_from_world = invert_transform(view.frontal.world_from_camera)
        prior = transform_points(camera_from_world, np.asarray(prior_world, np.float64))
        intrinsics = view.frontal.intrinsics
        depth = np.asarray(view.image.depth_mm, dtype=np.float64)
        height, width = depth.shape
        with np.errstate(invalid="ignore", divide="ignore"):
            uv = intrinsics.project(prior)
        finite = np.isfinite(uv).all(axis=-1) & (prior[:, 2] > 0)
        u = np.where(finite, np.rint(uv[:, 0]), -1).astype(np.int64)
        v = np.where(finite, np.rint(uv[:, 1]), -1).astype(np.int64)
        # the window of every joint at once: (32, (2w+1)^2) pixel depths, +inf outside the image / the body
        offsets = np.arange(-WINDOW_PX, WINDOW_PX + 1)
        du, dv = np.meshgrid(offsets, offsets)
        uu, vv = u[:, None] + du.reshape(-1), v[:, None] + dv.reshape(-1)
        inside = (uu >= 0) & (uu < width) & (vv >= 0) & (vv < height) & finite[:, None]
        window = np.full(uu.shape, np.inf)
        window[inside] = depth[vv[inside], uu[inside]]
        window[~np.isfinite(window)] = np.nan
        seen = np.isfinite(window).any(axis=1)
        surface = np.full(N_JOINTS, np.nan)
        if seen.any():
            surface[seen] = np.nanmedian(window[seen], axis=1)
        shoulder = np.linalg.norm(prior_world[_SHOULDERS[0]] - prior_world[_SHOULDERS[1]])
        scale = shoulder / _REFERENCE_SHOULDER_WIDTH_MM if np.isfinite(shoulder) and shoulder > 0 else 1.0
        target = surface + JOINT_RADIUS_MM * scale
        own = np.isfinite(JOINT_RADIUS_MM)
        occluded = seen & own & (np.abs(target - prior[:, 2]) > OCCLUDED_MM)
        slide = seen & own & ~occluded
        z = np.where(slide, target, prior[:, 2])
        with np.errstate(invalid="ignore", divide="ignore"):
            camera = prior * (z / prior[:, 2])[:, None]  # along the joint's viewing ray
        confidence = np.where(slide, int(Confidence.MEDIUM), int(Confidence.LOW)).astype(np.uint8)
        reported = seen & finite
        camera[~reported] = np.nan
        confidence[~reported] = int(Confidence.NONE)
        if not reported.any():
            return None
        return view.frontal.to_world(camera), confidence

    def retire(self, active: set[int]) -> None:
        """Nothing to forget (no state per person)."""

    def close(self) -> None:
        """Nothing to release."""


class PriorEchoTracker:
    """The control beside the stand-in: a "tracker" that ignores the virtual image and returns its prior (the
    realigned fused skeleton, i.e. skeleton fusion's output) unchanged, MEDIUM wherever finite.

    Whatever the stand-in scores beyond this control is what its slide along the rays adds; where the control
    scores better, the stand-in's figure shows the image path's plumbing, not a benefit of depth. Neither says
    what a real body tracker would find on the virtual image."""

    name = "prior-echo"
    description = "control: returns its prior (skeleton fusion's output) unchanged, never looks at the image"

    def track(
        self, person: int, view: PersonDepthView, prior_world: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """(32, 3) world joints and (32,) confidence: the prior as given; None without a prior."""
        if prior_world is None or not np.isfinite(prior_world).any():
            return None
        prior = np.asarray(prior_world, dtype=np.float64).copy()
        finite = np.isfinite(prior).all(axis=-1)
        prior[~finite] = np.nan
        return prior, np.where(finite, int(Confidence.MEDIUM), int(Confidence.NONE)).astype(np.uint8)

    def retire(self, active: set[int]) -> None:
        """Nothing to forget."""

    def close(self) -> None:
        """Nothing to release."""
