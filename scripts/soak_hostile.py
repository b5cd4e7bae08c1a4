"""Soak: a 16-sensor rig at 30 Hz for N minutes against a fusion node, with an adversary at 1 kHz.

    python scripts/soak_hostile.py --minutes 5 [--sensors 16] [--adversary-hz 1000] [--nice -10] [--json OUT.json]

A real ``skelfuse fuse`` process (loopback zenoh, peer mode) fuses the frames this script publishes for
``--sensors`` synthetic sensors at 30 Hz (one publisher session, paced on the monotonic clock; device times
of a synced rig). A second session, the adversary, publishes ``--adversary-hz`` payloads per second on the
rig's sensor keys, cycling through what a hostile peer can send: garbage, truncated frames, valid frames
stamped 0.9 s and 10^4 s in the future with forged sequences, 64-body frames, positions of 1e38 mm, a frame
on another sensor's key, unknown sensors, and a 4 MB payload once a second.

Measured and printed: fused frames received vs instants published, instants lost (published but never
fused), instants fused with every sensor, the node's RSS and its growth (last minus first, MB, and the
linear fit, MB/min) counted three ways: from the start (the node up, before any traffic), after 30 s, and after
``--warmup-s``; the node's resident memory by kind of mapping (heap, anonymous, stack, file; /proc/<pid>/smaps)
at the start and at the end; the fused publisher's put times (status ``info.fused_publish``); the node's
counters. Every 10 s, to tell CPU starvation from
a limit of the node: the machine's load average and CPU pressure (/proc/pressure/cpu), the node loop thread's
own CPU time and its run-queue wait (/proc/<pid>/task/<pid>/schedstat: time it was runnable but not running),
the whole node's CPU time, and the lag of each stage: this script's publishing behind its schedule, fused
frame received behind its instant's publishing, and the node's own added latency (its status); plus the
instants lost in that window, the change of the node's grouping counters that lose or thin out instants (late,
duplicate, dropped, out of window, resyncs, partial groups, deadline emits) and each sensor clock's re-learns.
A window that loses instants while the loop thread waits for a CPU is starvation;
one where the loop thread is busy the whole window is the node's limit.

``--nice N`` (root for N < 0) runs the node as its systemd unit does (``Nice=-10``): under ``nice -n N``, in its
own session whose scheduler autogroup gets nice N too (with ``kernel.sched_autogroup_enabled``, the kernel
shares the CPU between sessions first, so a process's nice alone does not count against other sessions'
work); this script takes the same priority. Not in the test suite (minutes long).
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

from skelfuse.apps.demo import sim_sensor_tables
from skelfuse.bench.latency import synthetic_frames
from skelfuse.cli.stamp import RunStamp
from skelfuse.service.zenoh_io import free_port, loopback_config, wait_for_port
from skelfuse.wire import keys
from skelfuse.wire.codec import decode_fused_frame, decode_status, encode_sensor_frame

RIG = "soak"
FPS = 30.0
WINDOW_S = 10.0
GROUPING_COUNTERS = ("late", "duplicate", "dropped", "out_of_window", "resyncs", "groups_partial", "deadline_emits")
"""Node counters recorded per window (their change): where the grouping loses or thins out instants."""


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


def memory_map_mb(pid: int) -> dict[str, float]:
    """The node's resident memory by kind of mapping, MB, from ``/proc/<pid>/smaps``.

    ``heap``: glibc's main arena (``[heap]``: Python objects, numpy arrays of the main thread); ``anon``:
    anonymous mappings (glibc's per-thread arenas, used by zenoh's threads, large numpy buffers, mmapped
    pymalloc arenas); ``stack``; ``file``: code and data of the binaries and shared libraries.
    """
    kinds = {"heap": 0, "anon": 0, "stack": 0, "file": 0}
    kind = "anon"
    try:
        text = Path(f"/proc/{pid}/smaps").read_text()
    except OSError:
        return {k: float("nan") for k in kinds}
    for line in text.splitlines():
        first = line.split(maxsplit=1)[0]
        if "-" in first and not first.endswith(":"):  # a mapping's header line: address range, perms, ..., name
            fields = line.split()
            name = fields[5] if len(fields) > 5 else ""
            kind = (
                "heap"
                if name == "[heap]"
                else "stack"
                if name.startswith("[stack")
                else "anon"
                if not name or name.startswith("[anon")
                else "file"
                if name.startswith("/")
                else "anon"
            )
        elif first == "Rss:":
            kinds[kind] += int(line.split()[1])
    return {k: round(v / 1024, 2) for k, v in kinds.items()}


def growth(rss: list[tuple[float, float]], after_s: float) -> tuple[float | None, float | None]:
    """(last minus the first sample at or after ``after_s`` s, MB; linear-fit slope after it, MB/min)."""
    tail = [(t, r) for t, r in rss if t >= after_s]
    if not tail:
        return None, None
    slope = float(np.polyfit([t for t, _ in tail], [r for _, r in tail], 1)[0]) * 60 if len(tail) >= 3 else None
    return round(tail[-1][1] - tail[0][1], 2), None if slope is None else round(slope, 4)


def zenoh_version() -> str:
    from importlib.metadata import version

    return version("eclipse-zenoh")


def schedstat(pid: int, tid: int | None = None) -> tuple[float, float]:
    """(CPU time, run-queue wait) in seconds of one thread (``tid``) or, summed, of every thread of ``pid``."""
    tids = [tid] if tid is not None else [int(t) for t in os.listdir(f"/proc/{pid}/task")]
    cpu = wait = 0
    for t in tids:
        try:
            fields = Path(f"/proc/{pid}/task/{t}/schedstat").read_text().split()
        except OSError:  # a thread that ended meanwhile
            continue
        cpu += int(fields[0])
        wait += int(fields[1])
    return cpu / 1e9, wait / 1e9


def machine_load() -> tuple[float, float | None]:
    """The 1-minute load average and the CPU pressure (share of the last 10 s some task waited for a CPU, %)."""
    load = float(Path("/proc/loadavg").read_text().split()[0])
    try:
        pressure = float(Path("/proc/pressure/cpu").read_text().split()[1].split("=")[1])
    except (OSError, IndexError, ValueError):
        pressure = None
    return load, pressure


def set_priority(pid: int, nice: int) -> str:
    """Give the scheduler autogroup of ``pid``'s session the nice value ``nice`` (what could be done, in words)."""
    try:
        Path(f"/proc/{pid}/autogroup").write_text(str(nice))
    except OSError as exc:
        return f"autogroup nice not set ({exc})"
    return f"autogroup nice {nice}"


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
    parser.add_argument(
        "--nice", type=int, default=None, help="run the node (and this script) at this nice value, e.g. -10 as root"
    )
    parser.add_argument(
        "--adversary-delay-s",
        type=float,
        default=2.0,
        help="the adversary starts this long after the rig (default 2); 0 races the rig's first frames, where a "
        "forged clock that speaks first on a sensor's key can take that sensor's clock (a known open fault)",
    )
    parser.add_argument(
        "--warmup-s",
        type=float,
        default=300.0,
        help="also report RSS growth from this many seconds in (default 300); growth from the start is always reported",
    )
    parser.add_argument(
        "--memory-probe",
        type=Path,
        default=None,
        help="run the node under scripts/node_memory_probe.py, which writes its memory breakdown (glibc malloc, "
        "Python blocks, gc objects, threads) to this JSONL file every 10 s",
    )
    parser.add_argument(
        "--trim-every",
        type=float,
        default=0.0,
        help="with --memory-probe: glibc malloc_trim(0) in the node every this many seconds (0: never)",
    )
    parser.add_argument(
        "--malloc-arena-max", type=int, default=None, help="run the node with MALLOC_ARENA_MAX set to this"
    )
    args = parser.parse_args()
    stamp = RunStamp.begin(sys.argv[1:], program=("python", "scripts/soak_hostile.py"))
    import zenoh

    duration_s = args.minutes * 60.0
    n_instants = int(duration_s * FPS)
    workdir = Path(tempfile.mkdtemp(prefix="skelfuse-soak-"))
    config = write_rig(workdir, args.sensors)
    port = free_port()
    node_log = open(workdir / "node.log", "wb")
    priority = [] if args.nice is None else ["nice", "-n", str(args.nice)]
    probe = (
        []
        if args.memory_probe is None
        else [
            str(Path(__file__).with_name("node_memory_probe.py")),
            str(args.memory_probe),
            "--trim-every",
            str(args.trim_every),
            "--",
        ]
    )
    env = dict(os.environ)
    if args.malloc_arena_max is not None:
        env["MALLOC_ARENA_MAX"] = str(args.malloc_arena_max)
    node = subprocess.Popen(
        [
            *priority,
            sys.executable,
            *(probe or ["-m", "skelfuse"]),
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
        env=env,
    )
    applied = "default priority"
    if args.nice is not None:
        applied = f"node nice {args.nice}, {set_priority(node.pid, args.nice)}"
        os.nice(args.nice - os.nice(0))
        if os.getsid(0) == os.getpid():  # this script leads its own session (started with setsid)
            applied += f"; this script nice {args.nice}, {set_priority(os.getpid(), args.nice)}"
        else:
            applied += f"; this script nice {args.nice} (its session's autogroup unchanged: start it with setsid)"
    try:
        if not wait_for_port(port, timeout_s=120):
            print("the node never listened; see", workdir / "node.log", file=sys.stderr)
            return 1
        fused_times: list[int] = []
        complete = [0]
        statuses: list = []
        lock = threading.Lock()
        session = zenoh.open(loopback_config(connect_ports=[port]))

        received_at: dict[int, float] = {}  # fused instant (device µs) -> monotonic time it was received

        def on_fused(sample) -> None:
            now = time.monotonic()
            frame = decode_fused_frame(sample.payload.to_bytes())
            with lock:
                fused_times.append(frame.time_us)
                received_at.setdefault(frame.time_us, now)
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
            if stop.wait(args.adversary_delay_s):  # the rig's clocks are learned first (see --adversary-delay-s)
                return
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
        windows: list[dict] = []
        publish_at: list[float] = []
        attacker = threading.Thread(target=attack, daemon=True)
        base_us = time.time_ns() // 1000
        start = time.monotonic()
        rss.append((0.0, rss_mb(node.pid)))  # from the start: the node is up and subscribed, no traffic yet
        memory_at_start = memory_map_mb(node.pid)
        attacker.start()
        next_window = start
        last_sched = (start, schedstat(node.pid, node.pid), schedstat(node.pid))
        print(
            f"soak: {args.sensors} sensors x 30 Hz for {args.minutes:g} min, adversary {args.adversary_hz:g} Hz; "
            f"{applied}",
            flush=True,
        )

        last_grouping: dict[str, int] = {}
        last_relearns: dict[str, int] = {}

        def grouping_changes(status) -> tuple[dict[str, int], dict[str, int]]:
            """Since the previous window: the node's grouping counters that lose or thin out instants, and each
            sensor's clock re-learns (status ``info.sensors.<id>.clock.relearns``), only those that moved."""
            counters = {name: int(status.counters.get(name, 0)) for name in GROUPING_COUNTERS}
            relearns = {
                sid: int((report.get("clock") or {}).get("relearns") or 0)
                for sid, report in status.info.get("sensors", {}).items()
            }
            moved = {k: v - last_grouping.get(k, 0) for k, v in counters.items() if v != last_grouping.get(k, 0)}
            stepped = {k: v - last_relearns.get(k, 0) for k, v in relearns.items() if v != last_relearns.get(k, 0)}
            last_grouping.update(counters)
            last_relearns.update(relearns)
            return moved, stepped

        def close_window(now: float) -> None:
            nonlocal last_sched
            then, (loop_cpu0, loop_wait0), (cpu0, wait0) = last_sched
            loop_cpu, loop_wait = schedstat(node.pid, node.pid)
            cpu, wait = schedstat(node.pid)
            wall = max(now - then, 1e-9)
            load, pressure = machine_load()
            with lock:
                recent = [st for st in statuses if st.time_ns >= time.time_ns() - int(wall * 1e9)]
                fused_n = len(fused_times)
            added = [st.info.get("node_added_ms", {}).get("p99") for st in recent]
            added = [a for a in added if a is not None]
            rss.append((now - start, rss_mb(node.pid)))
            memory = memory_map_mb(node.pid)
            publish = recent[-1].info.get("fused_publish") if recent else None
            grouping, relearns = grouping_changes(recent[-1]) if recent else ({}, {})
            windows.append(
                {
                    "t_s": round(now - start, 1),
                    "load_1min": load,
                    "cpu_pressure_pct": pressure,
                    "loop_cpu_pct": round(100 * (loop_cpu - loop_cpu0) / wall, 1),
                    "loop_runqueue_wait_pct": round(100 * (loop_wait - loop_wait0) / wall, 1),
                    "node_cpu_pct": round(100 * (cpu - cpu0) / wall, 1),
                    "node_runqueue_wait_pct": round(100 * (wait - wait0) / wall, 1),
                    "node_added_p99_ms": max(added) if added else None,
                    "samples_dropped": recent[-1].counters.get("samples_dropped") if recent else None,
                    "rss_mb": round(rss[-1][1], 1),
                    "rss_by_kind_mb": memory,
                    "fused_publish": publish,
                    "grouping": grouping,
                    "clock_relearns": relearns,
                }
            )
            last_sched = (now, (loop_cpu, loop_wait), (cpu, wait))
            w = windows[-1]
            print(
                f"  {w['t_s']:7.0f} s  RSS {w['rss_mb']:6.1f} MB  fused {fused_n}  hostile {sent_hostile[0]}  "
                f"load {load:.1f}  loop cpu {w['loop_cpu_pct']:.0f}% wait {w['loop_runqueue_wait_pct']:.0f}%  "
                f"node cpu {w['node_cpu_pct']:.0f}%  added p99 {w['node_added_p99_ms']} ms",
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
            now = time.monotonic()
            published_us.append(device_us)
            publish_at.append(now)
            if now >= next_window + WINDOW_S:
                close_window(now)
                next_window += WINDOW_S
        stop.set()
        attacker.join(5)
        time.sleep(2.0)
        close_window(time.monotonic())
        with lock:
            fused = set(fused_times)
            arrivals = dict(received_at)
            last_status = statuses[-1]
        # Per window: instants lost, this script's publishing lag, fused frames' lag behind their publishing.
        lag_publish: dict[int, list[float]] = {}
        lag_fused: dict[int, list[float]] = {}
        lost_in: dict[int, int] = {}
        for k, (t_us, at) in enumerate(zip(published_us, publish_at, strict=True)):
            index = min(int((at - start) // WINDOW_S), len(windows) - 1)
            lag_publish.setdefault(index, []).append(at - (start + k / FPS))
            if k >= 30 and t_us not in fused:  # the first second: tracks being born
                lost_in[index] = lost_in.get(index, 0) + 1
            if t_us in arrivals:
                lag_fused.setdefault(index, []).append(arrivals[t_us] - at)
        for index, w in enumerate(windows):
            w["instants_lost"] = lost_in.get(index, 0)
            for name, lags in (("publish_lag", lag_publish), ("fused_lag", lag_fused)):
                values = np.array(lags.get(index, [])) * 1e3
                w[f"{name}_p99_ms"] = round(float(np.percentile(values, 99)), 2) if values.size else None
                w[f"{name}_max_ms"] = round(float(values.max()), 2) if values.size else None
        lost = sum(lost_in.values())
        lossy = [w for w in windows if w["instants_lost"]]
        starved = [w for w in lossy if w["loop_runqueue_wait_pct"] >= 10.0 or (w["publish_lag_max_ms"] or 0) > 1000]
        busy = [w for w in lossy if w not in starved and w["loop_cpu_pct"] >= 90.0]
        warm = [(t, r) for t, r in rss if t >= 30.0]
        growth_start, slope_start = growth(rss, 0.0)
        growth_30s, slope = growth(rss, 30.0)
        growth_warm, slope_warm = growth(rss, args.warmup_s)
        kinds_last = windows[-1]["rss_by_kind_mb"]
        figures = {
            "sensors": args.sensors,
            "minutes": args.minutes,
            "priority": applied,
            "commit": subprocess.run(
                ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=Path(__file__).parent
            ).stdout.strip(),
            "adversary_delay_s": args.adversary_delay_s,
            "memory_probe": None if args.memory_probe is None else str(args.memory_probe),
            "trim_every_s": args.trim_every,
            "malloc_arena_max": args.malloc_arena_max,
            "instants_published": len(published_us),
            "fused_frames": len(fused_times),
            "instants_lost": lost,
            "instants_lost_in_starved_windows": sum(w["instants_lost"] for w in starved),
            "instants_lost_in_busy_windows": sum(w["instants_lost"] for w in busy),
            "instants_with_every_sensor": complete[0],
            "hostile_payloads_sent": sent_hostile[0],
            "node_rss_mb_at_start": round(rss[0][1], 2),
            "node_rss_mb_first_after_30s": warm[0][1] if warm else None,
            "node_rss_mb_last": rss[-1][1],
            "node_rss_growth_mb_from_start": growth_start,
            "node_rss_growth_mb_per_min_from_start": slope_start,
            "node_rss_growth_mb_after_30s": growth_30s,
            "node_rss_growth_mb_per_min": slope,
            "warmup_s": args.warmup_s,
            "node_rss_growth_mb_after_warmup": growth_warm,
            "node_rss_growth_mb_per_min_after_warmup": slope_warm,
            "node_rss_by_kind_mb_at_start": memory_at_start,
            "node_rss_by_kind_mb_last": kinds_last,
            "node_rss_by_kind_growth_mb_from_start": {
                k: round(kinds_last[k] - memory_at_start[k], 2) for k in memory_at_start
            },
            "fused_publish": windows[-1]["fused_publish"],
            "zenoh_version": zenoh_version(),
            "load_1min_max": max(w["load_1min"] for w in windows),
            "load_1min_median": float(np.median([w["load_1min"] for w in windows])),
            "loop_cpu_pct_max": max(w["loop_cpu_pct"] for w in windows),
            "loop_runqueue_wait_pct_max": max(w["loop_runqueue_wait_pct"] for w in windows),
            "node_cpu_seconds": round(schedstat(node.pid)[0], 1),
            "node_counters": last_status.counters,
            "clock_relearns": dict(last_relearns),
            "windows": windows,
            "stamp": stamp.finished(),  # command, revision, machine and load, as skelfuse's --json results
        }
        summary = {k: v for k, v in figures.items() if k != "windows"}
        print(json.dumps(summary, indent=2))
        for w in lossy:
            print(f"  lost {w['instants_lost']} in the window ending at {w['t_s']} s: {json.dumps(w)}")
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
