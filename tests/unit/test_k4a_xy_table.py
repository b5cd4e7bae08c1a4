"""Lens distortion in person clouds: the xy table built through ``k4a_calibration_2d_to_3d``.

The fake libk4a (tests/fake_k4a/fake_k4a.c) unprojects with our transcription of the Sensor SDK's
Brown-Conrady lens model; the binding builds the table the way the SDK's fastpointcloud sample does. Checked
here against two independent references: OpenCV's ``projectPoints`` (its rational model with tangential terms is
the same forward model) must put every valid ray back on its own pixel, and a numpy Newton inversion with a
numerical Jacobian must find the same rays and the same invalid pixels. Not the real SDK: none runs here.
"""

from __future__ import annotations

import ctypes

import numpy as np
import pytest
from fake_sdk import build_fake_libs_or_skip, harness

from skelfuse.fusion.camera import Intrinsics
from skelfuse.fusion.depth.cloud import person_clouds, pinhole_xy_table, voxelize
from skelfuse.sources.k4abt import depth_xy_table, load_k4a

WIDTH, HEIGHT, FX, FY, CX, CY = 320, 288, 252.0, 251.5, 163.0, 146.5
METRIC_RADIUS = 0.78  # cuts the image's corners: those pixels must come out invalid


PARAMS = {**harness.NFOV_BINNED_LENS, "fx": FX, "fy": FY, "cx": CX, "cy": CY}


@pytest.fixture(scope="module")
def table_and_lib(tmp_path_factory):
    libs = build_fake_libs_or_skip(tmp_path_factory.mktemp("fake_k4a_lens"), "1.1", "the lens model runs in")
    k4a = load_k4a(libs.k4a)
    k4a.fake_k4a_unprojections.restype = ctypes.c_int
    calibration = harness.distorted_calibration(WIDTH, HEIGHT, FX, FY, CX, CY, METRIC_RADIUS)
    table = depth_xy_table(k4a, ctypes.addressof(calibration))
    return table, k4a, calibration


def test_the_table_is_the_sdk_lens_model_of_every_pixel(table_and_lib) -> None:
    import cv2

    table, k4a, calibration = table_and_lib
    assert table.shape == (HEIGHT, WIDTH, 2) and table.dtype == np.float32
    assert k4a.fake_k4a_unprojections() == WIDTH * HEIGHT  # one SDK call per pixel, at depth 1 mm
    assert depth_xy_table(k4a, ctypes.addressof(calibration)) is table  # built once per calibration
    assert k4a.fake_k4a_unprojections() == WIDTH * HEIGHT
    valid = np.isfinite(table).all(axis=-1)
    assert 0 < (~valid).sum() < 0.2 * valid.size and not (~valid)[HEIGHT // 2, WIDTH // 2]

    # OpenCV's forward model: each valid ray lands back on its own pixel
    v, u = np.nonzero(valid)
    rays = np.concatenate([table[v, u].astype(np.float64), np.ones((u.size, 1))], axis=1)
    p = PARAMS
    camera = np.array([[FX, 0, CX], [0, FY, CY], [0, 0, 1]])
    coefficients = np.array([p["k1"], p["k2"], p["p1"], p["p2"], p["k3"], p["k4"], p["k5"], p["k6"]])
    pixels, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), camera, coefficients)
    error = np.hypot(pixels[:, 0, 0] - u, pixels[:, 0, 1] - v)
    assert error.max() < 2e-3  # px (float32 rays)

    # an independent numpy inversion finds the same rays and the same invalid pixels
    expected, radius = harness.brown_conrady_xy_table(WIDTH, HEIGHT, PARAMS)
    np.testing.assert_allclose(table[valid], expected[valid], atol=2e-6)
    decided = np.abs(radius - METRIC_RADIUS) > 0.01  # pixels clearly inside or outside the lens's valid radius
    assert np.array_equal(valid[decided], (radius <= METRIC_RADIUS)[decided])

    # and the distortion matters: towards the edges the ray is far from the pinhole's
    pinhole = pinhole_xy_table(Intrinsics(FX, FY, CX, CY, WIDTH, HEIGHT))
    shift_mm_at_2m = 2000.0 * np.linalg.norm(table - pinhole, axis=-1)
    assert shift_mm_at_2m[HEIGHT // 2, WIDTH // 2] < 1.0
    assert np.nanmax(shift_mm_at_2m) > 40.0


def test_a_person_cloud_is_lifted_through_the_table_and_invalid_pixels_are_dropped(table_and_lib) -> None:
    table, _, _ = table_and_lib
    depth = np.zeros((HEIGHT, WIDTH), np.uint16)
    depth[:, 180:] = 2000 + (np.arange(WIDTH - 180) % 53)[None, :]  # reaches the right-hand corners
    index = np.where(depth > 0, 0, 255).astype(np.uint8)
    (cloud,) = person_clouds(depth, index, table, voxel_mm=10.0)
    expected_rays, _ = harness.brown_conrady_xy_table(WIDTH, HEIGHT, PARAMS)
    keep = (depth > 0) & np.isfinite(table).all(axis=-1)
    assert (depth > 0).sum() - keep.sum() > 100  # corner pixels beyond the metric radius are in the block
    v, u = np.nonzero(keep)
    d = depth[v, u].astype(np.float64)
    lifted = np.stack([expected_rays[v, u, 0] * d, expected_rays[v, u, 1] * d, d], axis=1)
    expected, _, _ = voxelize(lifted, 10.0)
    np.testing.assert_allclose(cloud.points, expected, atol=0.02)
    (pinhole,) = person_clouds(depth, index, Intrinsics(FX, FY, CX, CY, WIDTH, HEIGHT), voxel_mm=10.0)
    assert pinhole.points.shape != cloud.points.shape or np.abs(pinhole.points - cloud.points).max() > 20.0
    assert np.isfinite(cloud.points).all()
