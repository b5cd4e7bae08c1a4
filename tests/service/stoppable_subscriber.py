"""A subscriber in its own process, for tests that stop it (SIGSTOP) to play a stalled or starved app.

    python stoppable_subscriber.py KEY PORT OUT.json [SO_RCVBUF]

Connects to ``tcp/127.0.0.1:PORT`` only (peer mode; no listener, no gossip, no scouting, so nothing else links to
it or reaches data through it; no shared memory, so every payload comes over that link), subscribes to KEY and, on
SIGTERM or on receiving ``END`` (a payload whose first 8 bytes are all 0xff, sent after the last frame: it arrives
after all that was sent before it), writes the first 8 bytes of each payload it received (little-endian int: the
tests' sequence numbers) to OUT.json.
``SO_RCVBUF`` (bytes) shrinks its TCP receive buffer (zenoh ``transport/link/tcp/so_rcvbuf``).
"""

from __future__ import annotations

import json
import signal
import sys
import threading
from pathlib import Path

import zenoh

from skelfuse.service.zenoh_io import loopback_config

END = b"\xff" * 8


def main() -> int:
    key, port, out = sys.argv[1], int(sys.argv[2]), Path(sys.argv[3])
    conf = loopback_config(connect_ports=[port])
    conf.insert_json5("listen/endpoints", "[]")
    conf.insert_json5("scouting/gossip/enabled", "false")
    conf.insert_json5("transport/shared_memory/enabled", "false")
    if len(sys.argv) > 4:
        conf.insert_json5("transport/link/tcp/so_rcvbuf", sys.argv[4])
    received: list[int] = []
    lock = threading.Lock()
    done = threading.Event()

    def on_sample(sample: zenoh.Sample) -> None:
        head = sample.payload.to_bytes()[:8]
        if head == END:
            done.set()
            return
        with lock:
            received.append(int.from_bytes(head, "little"))

    signal.signal(signal.SIGTERM, lambda *_: done.set())
    session = zenoh.open(conf)
    session.declare_subscriber(key, on_sample)
    print("subscribed", flush=True)
    while not done.wait(0.2):
        pass
    with lock:
        out.write_text(json.dumps(received))
    session.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
