"""``skelfuse bench depth``: its byte counts are those of the payloads it encodes, its table says what it measured."""

from __future__ import annotations

import json

from skelfuse.bench.depth import format_depth_bench
from skelfuse.cli import main
from skelfuse.wire.clouds import BODY_HEADER_SIZE, CLOUDS_HEADER_SIZE


def test_one_frame_of_one_person_is_counted_and_timed(capsys) -> None:
    assert main(["bench", "depth", "--people", "1", "--frames", "1", "--no-icp", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    (case,) = result["cases"]
    assert result["voxel_mm"] == 15.0 and case["n_people"] == 1 and case["n_sensors"] == 4
    # every sensor sees the person: header + a body block + id, 6 bytes a point, thousands of points
    assert case["bytes_per_sensor_frame"]["p50"] > CLOUDS_HEADER_SIZE + BODY_HEADER_SIZE + 6 * 1000
    assert case["megabits_per_second_mean"] == case["bytes_per_frame"]["p50"] * 30 * 8 / 1e6
    assert case["facing_error_deg"]["max"] < 10.0
    assert set(case["fuse_ms_per_person_frame"]) == {"no_icp"}
    table = format_depth_bench(result)
    assert "tracker time not included" in table and "Mbit/s" in table
