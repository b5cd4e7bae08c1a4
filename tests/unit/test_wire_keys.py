"""Key expressions: exact shapes, name validation, and parsing a received key back to its sensor or node."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from skelfuse.wire import keys


def _is_valid(name: str) -> bool:
    try:
        keys.validate_name(name)
    except ValueError:
        return False
    return True


valid_names = st.text(min_size=1, max_size=24).filter(_is_valid)


@pytest.mark.parametrize(
    ("built", "expected"),
    [
        pytest.param(keys.rig_prefix("lab"), "skelfuse/lab", id="prefix"),
        pytest.param(
            keys.sensor_skeletons("lab", "000123412512"), "skelfuse/lab/sensors/000123412512/skeletons", id="sensor"
        ),
        pytest.param(keys.all_sensor_skeletons("lab"), "skelfuse/lab/sensors/*/skeletons", id="all-sensors"),
        pytest.param(keys.fused_skeletons("lab"), "skelfuse/lab/fused/skeletons", id="fused"),
        pytest.param(keys.status("lab", "fusion"), "skelfuse/lab/status/fusion", id="status"),
        pytest.param(keys.all_status("lab"), "skelfuse/lab/status/*", id="all-status"),
        pytest.param(keys.calibration("lab"), "skelfuse/lab/calibration", id="calibration"),
        pytest.param(keys.alive("lab", "capture-01"), "skelfuse/lab/alive/capture-01", id="alive"),
        pytest.param(keys.all_alive("lab"), "skelfuse/lab/alive/*", id="all-alive"),
    ],
)
def test_key_shapes(built: str, expected: str) -> None:
    assert built == expected


@pytest.mark.parametrize(
    ("name", "fragment"),
    [
        pytest.param("", "empty", id="empty"),
        pytest.param("a/b", "'/'", id="slash"),
        pytest.param("a*", "'*'", id="star"),
        pytest.param("$*", "'$'", id="dollar"),
        pytest.param("a?b", "'?'", id="question"),
        pytest.param("a#b", "'#'", id="hash"),
        pytest.param("@admin", "verbatim", id="at-prefix"),
        pytest.param("lab 1", "whitespace", id="space"),
        pytest.param("lab\n", "whitespace", id="newline"),
        pytest.param("a\x00b", "control", id="nul"),
    ],
)
def test_bad_names_raise_value_error_naming_the_problem(name: str, fragment: str) -> None:
    with pytest.raises(ValueError, match="sensor name") as info:
        keys.sensor_skeletons("lab", name)
    assert fragment in str(info.value)
    with pytest.raises(ValueError, match="rig name"):
        keys.fused_skeletons(name)
    with pytest.raises(ValueError, match="node name"):
        keys.alive("lab", name)


def test_non_string_name_is_a_type_error() -> None:
    with pytest.raises(TypeError, match="rig name must be a str, got int"):
        keys.rig_prefix(7)  # type: ignore[arg-type]


@given(rig=valid_names, sensor=valid_names, node=valid_names)
def test_parse_inverts_build(rig: str, sensor: str, node: str) -> None:
    assert keys.parse_sensor_key(keys.sensor_skeletons(rig, sensor)) == sensor
    assert keys.parse_sensor_key(keys.sensor_skeletons(rig, sensor), rig=rig) == sensor
    assert keys.parse_status_key(keys.status(rig, node), rig=rig) == node
    assert keys.parse_alive_key(keys.alive(rig, node), rig=rig) == node


@pytest.mark.parametrize(
    "key",
    [
        pytest.param("skelfuse/lab/fused/skeletons", id="fused-key"),
        pytest.param("skelfuse/lab/sensors/*/skeletons", id="wildcard"),
        pytest.param("skelfuse/lab/sensors/a/b/skeletons", id="extra-level"),
        pytest.param("other/lab/sensors/a/skeletons", id="other-prefix"),
        pytest.param("skelfuse/lab/sensors/a/skeletons/x", id="suffix"),
        pytest.param("skelfuse/lab/sensors//skeletons", id="empty-chunk"),
        pytest.param("skelfuse/@lab/sensors/a/skeletons", id="verbatim-rig"),
    ],
)
def test_parse_sensor_key_rejects_other_keys(key: str) -> None:
    with pytest.raises(ValueError, match=r"key|name"):
        keys.parse_sensor_key(key)


def test_parse_sensor_key_checks_the_rig() -> None:
    with pytest.raises(ValueError, match="belongs to rig 'lab', expected rig 'studio'"):
        keys.parse_sensor_key("skelfuse/lab/sensors/A1/skeletons", rig="studio")


def test_keys_are_valid_zenoh_key_expressions() -> None:
    import zenoh

    sensor = zenoh.KeyExpr(keys.sensor_skeletons("lab", "000123412512"))
    assert zenoh.KeyExpr(keys.all_sensor_skeletons("lab")).intersects(sensor)
    assert not zenoh.KeyExpr(keys.all_sensor_skeletons("studio")).intersects(sensor)
    assert keys.parse_sensor_key(sensor, rig="lab") == "000123412512"  # a KeyExpr, as on sample.key_expr
    for key in (
        keys.fused_skeletons("lab"),
        keys.status("lab", "n"),
        keys.calibration("lab"),
        keys.alive("lab", "n"),
        keys.all_status("lab"),
        keys.all_alive("lab"),
    ):
        assert str(zenoh.KeyExpr(key)) == key
