"""Body trackers in worker processes: one process per person's virtual camera.

Some Body Tracking SDK versions allow one ``k4abt_tracker_t`` per process, and a tracker keeps temporal state
per stream, so several people's virtual cameras need several processes. :class:`TrackerPool` keeps one
worker process per person (track id), started when that person first needs it; each holds one
:class:`~skelfuse.sources.depth_tracker.VirtualCameraTracker`.

- The node writes a person's virtual DEPTH16 / IR16 images into the worker's shared-memory block and sends
  a few bytes through its pipe (so a send never waits on a full pipe: at most one small request is ever
  unread); it keeps the frontal view itself. The worker copies the images out, enqueues, pops (each wait
  ``wait_ms``) and sends the skeleton back in the virtual camera's frame; the node maps it to the world
  (:meth:`FrontalView.to_world`). Requests to every person's worker go out first
  and the answers are awaited together, so several people's trackers work at the same time.
- Never a stall: the node waits at most :meth:`TrackerPool.budget_s` (two SDK waits and a margin) per instant
  for all answers together. A person whose worker is still starting, still busy with an earlier image, or
  late, has no result this instant (counted). A worker that died (its pipe closed) or has left a request
  unanswered for ``hung_after_s`` is killed, counted, and started afresh on that person's next image.
- Shutdown (:meth:`TrackerPool.close`): every worker is asked to stop (its tracker is shut down and destroyed),
  then terminated and finally killed if it has not gone within ``close_timeout_s``. Workers ignore SIGINT
  (the node handles Ctrl-C and stops them) and exit by themselves when the node's end of the pipe closes.

Workers are started with the ``spawn`` method: the node runs zenoh threads, which a fork would copy mid-state.
"""

from __future__ import annotations

import logging
import multiprocessing
import multiprocessing.connection
import os
import signal
import time
from collections import Counter
from dataclasses import dataclass, field
from multiprocessing import resource_tracker, shared_memory
from typing import Any

import numpy as np

from skelfuse.fusion.camera import Intrinsics
from skelfuse.fusion.depth.frontal import FrontalView
from skelfuse.fusion.depth.pipeline import PersonDepthView
from skelfuse.fusion.depth.render import to_k4a_depth, to_k4a_ir
from skelfuse.sources.depth_tracker import VirtualCameraTracker
from skelfuse.sources.k4abt import K4abtLibrary, TrackerSettings, load_k4a

log = logging.getLogger("skelfuse.sources.tracker_pool")

MARGIN_S = 0.05
"""Added to the two SDK waits for the pipe's round trip and the worker's own work."""
START_TIMEOUT_S = 60.0
"""A worker that has not said "ready" (SDK loaded, tracker created) after this long is taken for hung."""


@dataclass(frozen=True)
class WorkerSpec:
    """What a worker process needs to open its tracker (picklable)."""

    k4a_path: str
    k4abt_path: str
    abi: str
    intrinsics: Intrinsics
    settings: TrackerSettings
    wait_ms: int


def _worker_main(connection: Any, spec: WorkerSpec, block_name: str) -> None:
    """A tracker process: open the SDK and one tracker, then answer image requests until told to stop."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the node handles Ctrl-C and stops its workers
    block = shared_memory.SharedMemory(name=block_name)
    # The node owns the block and unlinks it; without this, this process's exit would unlink it too.
    resource_tracker.unregister(block._name, "shared_memory")  # type: ignore[attr-defined]  # the private name the tracker registered (with its leading "/")
    try:
        _serve(connection, spec, block)
    finally:
        block.close()


def _serve(connection: Any, spec: WorkerSpec, block: shared_memory.SharedMemory) -> None:
    try:
        tracker = VirtualCameraTracker(
            load_k4a(spec.k4a_path), K4abtLibrary.load(spec.k4abt_path, abi=spec.abi), spec.intrinsics, spec.settings
        )
    except Exception as exc:  # reported to the node, which counts it; nothing to serve
        connection.send(("failed", -1, f"{type(exc).__name__}: {exc}"))
        return
    connection.send(("ready", -1, os.getpid()))
    try:
        while True:
            try:
                request = connection.recv()
            except (EOFError, OSError):  # the node is gone
                break
            if request is None:
                break
            sequence, has_ir = request
            depth, ir = _images(block, spec.intrinsics, has_ir)
            try:
                connection.send(("result", sequence, _track_one(tracker, depth, ir, spec.wait_ms)))
            except Exception as exc:
                connection.send(("error", sequence, f"{type(exc).__name__}: {exc}"))
    finally:
        tracker.close()


def _image_bytes(intrinsics: Intrinsics) -> int:
    return intrinsics.width * intrinsics.height * 2


def _buffer(block: shared_memory.SharedMemory) -> memoryview:
    """The block's memory (None only after ``close()``, which the pool does last)."""
    if block.buf is None:
        raise ValueError(f"shared memory block {block.name} is closed")
    return block.buf


def _images(block: shared_memory.SharedMemory, intrinsics: Intrinsics, has_ir: bool) -> tuple[np.ndarray, Any]:
    """Copies of the DEPTH16 (and IR16) image the node wrote into the block."""
    shape, n = (intrinsics.height, intrinsics.width), _image_bytes(intrinsics)
    buffer = _buffer(block)
    depth = np.frombuffer(buffer, dtype=np.uint16, count=n // 2).reshape(shape).copy()
    ir = np.frombuffer(buffer, dtype=np.uint16, count=n // 2, offset=n).reshape(shape).copy() if has_ir else None
    return depth, ir


def _track_one(tracker: VirtualCameraTracker, depth: np.ndarray, ir: np.ndarray | None, wait_ms: int) -> tuple | None:
    """Enqueue one image pair and pop its result: (positions_camera (32, 3), confidence (32,)) or None."""
    time_us = tracker.submit_images(depth, ir, timeout_ms=wait_ms)
    if time_us is None:
        return None
    for _ in range(4):  # results of earlier images the node gave up on come first: skip them
        found = tracker.collect_camera(timeout_ms=wait_ms)
        if found is None:
            return None
        if found.device_time_us >= time_us:
            return (found.positions_camera, found.confidence) if found.device_time_us == time_us else None
    return None


@dataclass
class _Worker:
    process: Any
    connection: Any
    block: shared_memory.SharedMemory
    started: float
    ready: bool = False
    outstanding: dict[int, tuple[FrontalView, float]] = field(default_factory=dict)


@dataclass
class PoolCounters:
    """What the pool did, for the node's status (``info.depth.tracker_processes``)."""

    started: int = 0
    restarts: Counter[str] = field(default_factory=Counter)
    """Workers killed and started afresh, by reason: "died", "hung", "failed" (could not open the SDK)."""
    starting: int = 0
    busy: int = 0
    late: int = 0
    errors: int = 0


class TrackerPool:
    """One tracker process per person (see the module docstring).

    Parameters
    ----------
    spec : the SDK paths, virtual intrinsics, tracker settings and the SDK wait (``[depth] tracker_wait_ms``).
    hung_after_s : a request unanswered for this long marks its worker hung (killed, restarted).
    close_timeout_s : how long :meth:`close` gives the workers to stop before they are killed.
    """

    def __init__(self, spec: WorkerSpec, *, hung_after_s: float = 2.0, close_timeout_s: float = 1.0) -> None:
        self.spec = spec
        self.hung_after_s = float(hung_after_s)
        self.close_timeout_s = float(close_timeout_s)
        self.counters = PoolCounters()
        self._context = multiprocessing.get_context("spawn")
        self._workers: dict[int, _Worker] = {}
        self._sequence = 0

    @property
    def budget_s(self) -> float:
        """The longest one instant waits for the workers' answers (all people together)."""
        return 2 * self.spec.wait_ms / 1000.0 + MARGIN_S

    def persons(self) -> set[int]:
        return set(self._workers)

    def pids(self) -> dict[int, int]:
        """Worker process id of each person (for tests and the log)."""
        return {person: int(worker.process.pid) for person, worker in self._workers.items()}

    # -- one instant -------------------------------------------------------------------------------------------

    def track_many(
        self, requests: list[tuple[int, PersonDepthView]]
    ) -> list[tuple[np.ndarray, np.ndarray] | Exception | None]:
        """Each person's skeleton in the world (positions (32, 3), confidence (32,)), None where there is none
        this instant, or the worker's error; waits at most :attr:`budget_s` in all."""
        now = time.monotonic()
        self._check(now)
        sent: dict[int, tuple[int, int]] = {}  # request index -> (person, sequence)
        results: list[tuple[np.ndarray, np.ndarray] | Exception | None] = [None] * len(requests)
        for index, (person, view) in enumerate(requests):
            worker = self._workers.get(person) or self._start(person)
            self._drain(person, worker)
            if person not in self._workers:  # it died or failed meanwhile (counted): a new one starts next time
                continue
            if not worker.ready:
                self.counters.starting += 1
                continue
            if worker.outstanding:  # still on an earlier image: this one is skipped, never queued up
                self.counters.busy += 1
                continue
            depth = to_k4a_depth(view.image.depth_mm)
            ir = None if view.image.ir is None else to_k4a_ir(view.image.ir)
            if depth.shape != (self.spec.intrinsics.height, self.spec.intrinsics.width):
                results[index] = ValueError(f"a virtual image of {depth.shape} for a {self.spec.intrinsics} camera")
                continue
            n = _image_bytes(self.spec.intrinsics)
            buffer = _buffer(worker.block)
            buffer[:n] = depth.astype("<u2").tobytes()  # the worker has copied the previous one out
            if ir is not None:
                buffer[n : 2 * n] = ir.astype("<u2").tobytes()
            self._sequence += 1
            try:
                worker.connection.send((self._sequence, ir is not None))
            except (OSError, ValueError):  # its pipe is broken: it died
                self._restart(person, "died")
                continue
            worker.outstanding[self._sequence] = (view.frontal, now)
            sent[index] = (person, self._sequence)
        deadline = now + self.budget_s
        waiting = dict(sent)
        while waiting:
            left = deadline - time.monotonic()
            connections = {self._workers[p].connection: p for p, _ in waiting.values() if p in self._workers}
            if left <= 0 or not connections:
                break
            for ready in multiprocessing.connection.wait(list(connections), timeout=left):
                person = connections[ready]
                answers = self._drain(person, self._workers[person])
                for index, (p, sequence) in list(waiting.items()):
                    if p == person and sequence in answers:
                        results[index] = answers[sequence]
                        del waiting[index]
                    elif p == person and person not in self._workers:  # it died meanwhile
                        del waiting[index]
        self.counters.late += len(waiting)
        return results

    def retire(self, active: set[int]) -> None:
        """Stop the workers of people not in ``active``."""
        for person in [p for p in self._workers if p not in active]:
            self._stop([self._workers.pop(person)])

    def rename(self, old: int, new: int) -> None:
        if old in self._workers and new not in self._workers:
            self._workers[new] = self._workers.pop(old)

    def close(self) -> None:
        """Stop every worker: asked, then terminated, then killed, within :attr:`close_timeout_s` in all."""
        workers, self._workers = list(self._workers.values()), {}
        self._stop(workers)

    # -- workers -------------------------------------------------------------------------------------------------

    def _start(self, person: int) -> _Worker:
        parent, child = self._context.Pipe(duplex=True)
        block = shared_memory.SharedMemory(create=True, size=2 * _image_bytes(self.spec.intrinsics))
        process = self._context.Process(
            target=_worker_main, args=(child, self.spec, block.name), name=f"skelfuse-tracker-{person}", daemon=True
        )
        process.start()
        child.close()  # the child's end lives in the child: its death closes the pipe
        worker = self._workers[person] = _Worker(process, parent, block, time.monotonic())
        self.counters.started += 1
        log.info("tracker process for person %d started (pid %d)", person, process.pid)
        return worker

    def _drain(self, person: int, worker: _Worker) -> dict[int, Any]:
        """Every message the worker has sent: "ready" marks it ready; answers of outstanding requests are
        returned by sequence (mapped to the world); stale ones are dropped. A closed pipe: restarted."""
        answers: dict[int, Any] = {}
        try:
            while worker.connection.poll(0):
                kind, sequence, payload = worker.connection.recv()
                if kind == "ready":
                    worker.ready = True
                elif kind == "failed":
                    log.error("tracker process for person %d could not open its tracker: %s", person, payload)
                    self.counters.errors += 1
                    self._restart(person, "failed")
                    break
                else:
                    entry = worker.outstanding.pop(sequence, None)
                    if entry is None:
                        continue
                    if kind == "error":
                        self.counters.errors += 1
                        answers[sequence] = RuntimeError(f"tracker process for person {person}: {payload}")
                    elif payload is None:
                        answers[sequence] = None
                    else:
                        positions, confidence = payload
                        answers[sequence] = (entry[0].to_world(np.asarray(positions, np.float64)), confidence)
        except (EOFError, OSError):
            self._restart(person, "died")
        return answers

    def _check(self, now: float) -> None:
        """Restart workers that died, never became ready, or sit on a request for too long."""
        for person, worker in list(self._workers.items()):
            if not worker.process.is_alive():
                self._restart(person, "died")
            elif not worker.ready and now - worker.started > max(START_TIMEOUT_S, self.hung_after_s):
                self._restart(person, "hung")
            elif worker.outstanding and now - min(t for _, t in worker.outstanding.values()) > self.hung_after_s:
                self._restart(person, "hung")

    def _restart(self, person: int, reason: str) -> None:
        worker = self._workers.pop(person, None)
        if worker is None:
            return
        self.counters.restarts[reason] += 1
        if sum(self.counters.restarts.values()) == 1 or self.counters.restarts[reason] % 100 == 1:
            log.error(
                "tracker process for person %d (pid %s) %s; killed, a new one starts with the person's next image "
                "(restarts so far: %s)",
                person,
                worker.process.pid,
                {"died": "died", "hung": "stopped answering", "failed": "could not open its tracker"}[reason],
                dict(self.counters.restarts),
            )
        self._stop([worker], timeout_s=0.0)

    def _stop(self, workers: list[_Worker], timeout_s: float | None = None) -> None:
        """Ask, then terminate, then kill; bounded by ``timeout_s`` (default :attr:`close_timeout_s`) in all."""
        deadline = time.monotonic() + (self.close_timeout_s if timeout_s is None else timeout_s)
        for worker in workers:
            try:
                worker.connection.send(None)
            except (OSError, ValueError):
                pass
        for step in ("ask", "terminate", "kill"):
            for worker in workers:
                if step == "terminate" and worker.process.is_alive():
                    worker.process.terminate()
                elif step == "kill" and worker.process.is_alive():
                    worker.process.kill()
            share = max(0.0, deadline - time.monotonic()) / (2 if step == "ask" else 1)
            for worker in workers:
                worker.process.join(share if step != "kill" else 1.0)
            if not any(worker.process.is_alive() for worker in workers):
                break
        for worker in workers:
            worker.connection.close()
            worker.block.close()
            worker.block.unlink()
            if not worker.process.is_alive():
                worker.process.close()

    def report(self) -> dict[str, Any]:
        c = self.counters
        return {
            "workers": len(self._workers),
            "started": c.started,
            "restarts": dict(c.restarts),
            "starting": c.starting,
            "busy": c.busy,
            "late": c.late,
            "errors": c.errors,
        }
