"""Soak: a 16-sensor rig at 30 Hz for N minutes against a fusion node, with an adversary at 1 kHz.

    python scripts/soak_hostile.py --minutes 5 [--sensors 16] [--adversary-hz 1000] [--json OUT.json]

A real ``skelfuse fuse`` process (loopback zenoh, peer mode) fuses the frames this script publishes for
``--sensors`` synthetic sensors at 30 Hz (one publisher session, paced on the monotonic clock; device times
of a synced rig). A second session, the adversary, publishes ``--adversary-hz`` payloads per second on the
rig's sensor keys, cycling through what a hostile peer can send: garbage, truncated frames, valid frames
stamped 0.9 s and 10^4 s in the future with forged sequences, 64-body frames, positions of 1e38 mm, a frame
on another sensor's key, unknown sensors, and a 4 MB payload once a second.

Measured and printed: fused frames received vs instants published, instants lost (published but never
fused), instants fused with every sensor, the node's RSS every 10 s and its growth (MB/min, linear fit after
a 30 s warm-up), and the node's reject counters. Not in the test suite (minutes long).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from skelfuse.bench.latency import synthetic_frames
from skelfuse.demo import sim_sensor_tables
from skelfuse.service.zenoh_io import free_port, loopback_config, wait_for_port
from skelfuse.wire import keys
from skelfuse.wire.codec import decode_fused_frame, decode_status, encode_sensor_frame

RIG = "soak"
FPS = 30.0


def write_rig(directory: Path, n_sensors: int) -> Path:
    lines = [
        "[rig]",
        f'name = "{RIG}"',
        "",
        "[sync]",
        'by = "device"',
        "fps = 30.0",
        "tolerance_ms = 10.0",
        "deadline_ms = 60.0",
        "",
        "[node]",
        "status_period_s = 1.0",
        "",
    ]
    lines += sim_sensor_tables(n_sensors)
    path = directory / "rig-soak.toml"
    path.write_text("\n".join(lines), encoding="utf-8")
    return path


def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def hostile_payloads(template, sensor_ids: list[str]) -> list[tuple[str, bytes]]:
    """(key, payload) pairs of every kind the adversary sends (the 4 MB one is sent separately)."""
    good = encode_sensor_frame(template)
    crowd = dataclasses.replace(
        template,
        body_ids=np.arange(64, dtype=np.uint32),
        positions=np.repeat(template.positions, 64, axis=0) + np.arange(64, dtype=np.float32)[:, None, None] * 50,
        orientations=np.repeat(template.orientations, 64, axis=0),
        confidence=np.repeat(template.confidence, 64, axis=0),
    )
    far = dataclasses.replace(template, positions=np.full_like(template.positions, 1e38))
    key = keys.sensor_skeletons(RIG, sensor_ids[1])
    return [
        (key, b"\x00garbage" * 8),
        (key, good[: len(good) // 2]),
        (key, encode_sensor_frame(far)),
        (key, encode_sensor_frame(crowd)),
        (keys.sensor_skeletons(RIG, sensor_ids[2]), good),  # another sensor's key
        (
            keys.sensor_skeletons(RIG, "intruder"),
            encode_sensor_frame(dataclasses.replace(template, sensor_id="intruder")),
        ),
    ]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--minutes", type=float, default=5.0)
    parser.add_argument("--sensors", type=int, default=16)
    parser.add_argument("--adversary-hz", type=float, default=1000.0)
    parser.add_argument("--json", type=Path, default=None, help="write the figures as JSON here too")
    args = parser.parse_args()
    import zenoh

    duration_s = args.minutes * 60.0
    n_instants = int(duration_s * FPS)
    workdir = Path(tempfile.mkdtemp(prefix="skelfuse-soak-"))
    config = write_rig(workdir, args.sensors)
    port = free_port()
    node_log = open(workdir / "node.log", "wb")
    node = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "skelfuse",
            "fuse",
            "--config",
            str(config),
            "--no-view",
            "--duration",
            str(duration_s + 60),
            "--zenoh-mode",
            "peer",
            "--no-multicast-scouting",
            "--zenoh-listen",
            f"tcp/127.0.0.1:{port}",
        ],
        stdout=node_log,
        stderr=subprocess.STDOUT,
        start_new_session=True,
    )
    try:
        if not wait_for_port(port, timeout_s=120):
            print("the node never listened; see", workdir / "node.log", file=sys.stderr)
            return 1
        fused_times: list[int] = []
        complete = [0]
        statuses: list = []
        lock = threading.Lock()
        session = zenoh.open(loopback_config(connect_ports=[port]))

        def on_fused(sample) -> None:
            frame = decode_fused_frame(sample.payload.to_bytes())
            with lock:
                fused_times.append(frame.time_us)
                complete[0] += bool(frame.n_persons and frame.contributors.any(axis=0).all())

        def on_status(sample) -> None:
            status = decode_status(sample.payload.to_bytes())
            if status.role == "fusion":
                with lock:
                    statuses.append(status)

        session.declare_subscriber(keys.fused_skeletons(RIG), on_fused)
        session.declare_subscriber(keys.all_status(RIG), on_status)
        while True:  # the node subscribes once it is up: wait for its first status
            with lock:
                if statuses:
                    break
            time.sleep(0.1)
        frames = synthetic_frames(args.sensors, 300, seed=3)  # a 10 s take, looped
        sensor_ids = [f.sensor_id for f in frames[0]]
        publishers = {sid: session.declare_publisher(keys.sensor_skeletons(RIG, sid)) for sid in sensor_ids}
        adversary = zenoh.open(loopback_config(connect_ports=[port]))
        hostile = hostile_payloads(frames[0][1], sensor_ids)
        stop = threading.Event()
        sent_hostile = [0]
        published_us: list[int] = []
        clock = {"device_us": 0, "seq": 0}

        def attack() -> None:
            period = 1.0 / args.adversary_hz
            big = b"\x01" * (4 << 20)
            next_t, next_big, i = time.monotonic(), time.monotonic() + 1.0, 0
            key = keys.sensor_skeletons(RIG, sensor_ids[1])
            while not stop.is_set():
                now = time.monotonic()
                if now >= next_big:
                    adversary.put(key, big)
                    next_big += 1.0
                kind = i % (len(hostile) + 2)
                if kind < len(hostile):
                    adversary.put(*hostile[kind])
                else:  # valid frames from the future (0.9 s, then 10^4 s) with forged sequences
                    ahead = 900_000 if kind == len(hostile) else 10**10
                    forged = dataclasses.replace(
                        frames[0][1], sequence=clock["seq"] + 10**9, device_time_us=clock["device_us"] + ahead
                    )
                    adversary.put(key, encode_sensor_frame(forged))
                sent_hostile[0] += 1
                i += 1
                next_t += period
                delay = next_t - time.monotonic()
                if delay > 0:
                    time.sleep(delay)

        rss: list[tuple[float, float]] = []
        attacker = threading.Thread(target=attack, daemon=True)
        base_us = time.time_ns() // 1000
        start = time.monotonic()
        attacker.start()
        next_rss = start
        print(
            f"soak: {args.sensors} sensors x 30 Hz for {args.minutes:g} min, adversary {args.adversary_hz:g} Hz",
            flush=True,
        )
        for k in range(n_instants):
            due = start + k / FPS
            delay = due - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            device_us = base_us + round(k * 1e6 / FPS)
            clock["device_us"], clock["seq"] = device_us, k
            for i, frame in enumerate(frames[k % len(frames)]):
                stamped = dataclasses.replace(
                    frame, sequence=k, device_time_us=device_us + 160 * i, host_time_ns=time.time_ns()
                )
                publishers[frame.sensor_id].put(encode_sensor_frame(stamped))
            published_us.append(device_us)
            now = time.monotonic()
            if now >= next_rss:
                rss.append((now - start, rss_mb(node.pid)))
                next_rss += 10.0
                print(
                    f"  {now - start:7.0f} s  node RSS {rss[-1][1]:7.1f} MB  fused {len(fused_times)}"
                    f"  hostile sent {sent_hostile[0]}",
                    flush=True,
                )
        stop.set()
        attacker.join(5)
        time.sleep(2.0)
        rss.append((time.monotonic() - start, rss_mb(node.pid)))
        with lock:
            fused = set(fused_times)
            last_status = statuses[-1]
        lost = [t for t in published_us[30:] if t not in fused]  # the first second: tracks being born
        warm = [(t, r) for t, r in rss if t >= 30.0]
        slope = float(np.polyfit([t for t, _ in warm], [r for _, r in warm], 1)[0]) * 60 if len(warm) >= 3 else None
        figures = {
            "sensors": args.sensors,
            "minutes": args.minutes,
            "instants_published": len(published_us),
            "fused_frames": len(fused_times),
            "instants_lost": len(lost),
            "instants_with_every_sensor": complete[0],
            "hostile_payloads_sent": sent_hostile[0],
            "node_rss_mb_first_after_30s": warm[0][1] if warm else None,
            "node_rss_mb_last": rss[-1][1],
            "node_rss_growth_mb_per_min": None if slope is None else round(slope, 4),
            "node_counters": last_status.counters,
        }
        print(json.dumps(figures, indent=2))
        if args.json is not None:
            args.json.write_text(json.dumps(figures, indent=2))
        adversary.close()
        session.close()
        return 0 if not lost else 1
    finally:
        if node.poll() is None:
            os.killpg(node.pid, signal.SIGTERM)
            try:
                node.wait(20)
            except subprocess.TimeoutExpired:
                os.killpg(node.pid, signal.SIGKILL)
        node_log.close()


if __name__ == "__main__":
    sys.exit(main())
