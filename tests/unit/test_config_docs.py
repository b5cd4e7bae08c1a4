"""docs/configuration.md documents exactly the keys the config parser reads, and ``[record]`` keys do something.

The parser is its own schema: a table holding an unknown key is refused with the list of the keys that table
allows (``config.checks.Table.done``), so each documented table is compared with that list.
"""

from __future__ import annotations

import copy
import re
import threading
from pathlib import Path
from typing import Any

import pytest
from recorder_progress import RecorderProgress

from skelfuse.config import parse_rig_config
from skelfuse.schema.errors import ConfigError
from skelfuse.service.lifecycle import Lifecycle, RunLimits
from skelfuse.service.recorder import run_recorder
from skelfuse.service.worker import SimSource
from skelfuse.service.zenoh_io import free_port, loopback_config
from skelfuse.wire import keys
from skelfuse.wire.codec import encode_sensor_frame
from waiting import wait_for_subscriber

DOC = Path(__file__).resolve().parents[2] / "docs" / "configuration.md"
BOGUS = "zz_not_a_key"

MINIMAL: dict[str, Any] = {
    "rig": {"name": "r"},
    "sensors": [
        {
            "id": "a",
            "source": "kinect",
            "sync": {"role": "standalone"},
            "kinect": {"serial": "1", "tracker": {"processing_mode": "cpu"}},
        },
        {"id": "b", "source": "replay", "replay": {"file": "x.mcap"}},
        {
            "id": "c",
            "source": "sim",
            "sim": {"seed": 1},
            "world_from_sensor": [[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 0], [0, 0, 0, 1.0]],
        },
    ],
}

# documented table heading -> (path of the dict to put the unknown key in, nested tables documented apart)
TABLES: dict[str, tuple[tuple[Any, ...], tuple[str, ...]]] = {
    "[rig]": (("rig",), ()),
    "[[sensors]]": ((("sensors", 0), ("sensors", 1), ("sensors", 2)), ("sync", "kinect", "replay", "sim")),
    "sensors[i].sync": (("sensors", 0, "sync"), ()),
    "sensors[i].kinect": (("sensors", 0, "kinect"), ("tracker",)),
    "sensors[i].kinect.tracker": (("sensors", 0, "kinect", "tracker"), ()),
    "sensors[i].replay": (("sensors", 1, "replay"), ()),
    "sensors[i].sim": (("sensors", 2, "sim"), ()),
    "[calibration]": (("calibration",), ()),
    "[sync]": (("sync",), ()),
    "[fusion]": (("fusion",), ("params",)),
    "[depth]": (("depth",), ()),
    "[zenoh]": (("zenoh",), ("config", "tls")),
    "[zenoh.tls]": (("zenoh", "tls"), ()),
    "[node]": (("node",), ()),
    "[capture]": (("capture",), ()),
    "[rerun]": (("rerun",), ()),
    "[record]": (("record",), ()),
    "[intake]": (("intake",), ()),
    "[stream]": (("stream",), ()),
}


def documented_tables() -> dict[str, set[str]]:
    """Heading (as in TABLES) -> the keys of the table right under it."""
    tables: dict[str, set[str]] = {}
    current = None
    for line in DOC.read_text(encoding="utf-8").splitlines():
        heading = re.match(r"#{2,3} `([^`]+)`", line)
        if heading:
            current = heading.group(1)
            tables.setdefault(current, set())
            continue
        row = re.match(r"\| `([a-z_0-9]+)`\s*\|", line)
        if row and current is not None:
            tables[current].add(row.group(1))
    return tables


#: tables that need a key of their own before the parser looks at the others
REQUIRED_KEYS: dict[tuple[Any, ...], dict[str, Any]] = {("zenoh", "tls"): {"directory": "certs"}}


def allowed_keys(path: tuple[Any, ...]) -> set[str]:
    data = copy.deepcopy(MINIMAL)
    if path in REQUIRED_KEYS:
        data.setdefault(path[0], {})[path[1]] = dict(REQUIRED_KEYS[path])
    target: Any = data
    for step in path:
        if isinstance(target, dict):
            target = target.setdefault(step, {})
        else:
            target = target[step]
    target[BOGUS] = 1
    with pytest.raises(ConfigError, match="keys allowed in") as refused:
        parse_rig_config(data)
    return set(str(refused.value).split("keys allowed in ")[1].split(": ", 1)[1].split(", "))


@pytest.mark.parametrize("heading", sorted(TABLES))
def test_documented_keys_are_the_keys_the_parser_reads(heading: str) -> None:
    documented = documented_tables()
    assert heading in documented, f"docs/configuration.md has no section `{heading}`"
    path, nested = TABLES[heading]
    paths = path if isinstance(path[0], tuple) else (path,)  # [[sensors]]: one sensor of each source
    reads = set().union(*(allowed_keys(p) for p in paths))
    assert documented[heading] | set(nested) == reads, (
        f"`{heading}`: documented {sorted(documented[heading])}, the parser reads {sorted(reads)}"
    )


def test_every_documented_table_is_checked() -> None:
    free_form = {"[fusion.params]", "[zenoh.config]"}  # passthroughs: any FusionParams field / zenoh path
    tables = {h for h, rows in documented_tables().items() if rows and h not in free_form}
    assert tables <= set(TABLES), f"tables documented but not compared with the parser: {tables - set(TABLES)}"


def test_record_with_nothing_to_record_is_refused(tmp_path: Path) -> None:
    cfg = parse_rig_config({**MINIMAL, "record": {"sensors": False, "fused": False}})
    with pytest.raises(ConfigError, match="nothing to record"):
        run_recorder(cfg, None, output=tmp_path / "x.mcap", limits=RunLimits(duration_s=1), lifecycle=Lifecycle())


@pytest.mark.parametrize("record_sensors", [True, False])
@pytest.mark.live
def test_record_sensors_decides_whether_sensor_frames_are_recorded(
    tmp_path: Path, record_sensors: bool, recorder_progress: RecorderProgress
) -> None:
    import zenoh

    pose = [[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 0], [0, 0, 0, 1.0]]
    cfg = parse_rig_config(
        {
            "rig": {"name": "rec"},
            "sensors": [{"id": "s0", "source": "sim", "world_from_sensor": pose}],
            "record": {"sensors": record_sensors, "directory": str(tmp_path / "takes")},
        }
    )
    port = free_port()
    lifecycle = Lifecycle("recorder")
    result: dict[str, Any] = {}
    recorder = threading.Thread(
        target=lambda: result.update(
            report=run_recorder(
                cfg,
                loopback_config(listen_port=port),
                output=None,
                limits=RunLimits(duration_s=20),
                lifecycle=lifecycle,
            )
        ),
        daemon=True,
    )
    recorder.start()
    source = SimSource(cfg, "s0", take_duration_s=1.0, clock_ns=lambda: 10**18)
    with zenoh.open(loopback_config(connect_ports=[port])) as session:
        publisher = session.declare_publisher(keys.sensor_skeletons("rec", "s0"))
        end = session.declare_publisher(keys.fused_skeletons("rec"))
        wait_for_subscriber(end, "the recorder's subscription")  # declared with the sensor one, if any
        for n in range(30):
            frame = source.frame_at(n)
            if frame is not None:
                publisher.put(encode_sensor_frame(frame))
        end.put(recorder_progress.end_marker())
        recorder_progress.wait_for_end_marker()
    lifecycle.request_exit()
    recorder.join(10.0)
    report = result["report"]
    assert report.path.parent == tmp_path / "takes"  # [record] directory, created
    assert (report.frames_written > 20) == record_sensors, report.frames_written
