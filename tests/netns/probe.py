"""A zenoh client for the network-namespace tests, run inside a namespace with ``ip netns exec``.

``python probe.py listen CONFIG IDENTITY ENDPOINT OUT``: record every sensor and fused payload (hex, with
  its key and arrival time) as JSON lines in OUT until SIGTERM.
``python probe.py forge CONFIG IDENTITY ENDPOINT KEY...``: publish a marked payload on each KEY, 20 times.
``python probe.py connect CONFIG IDENTITY ENDPOINT``: print "connected" or "refused: <reason>".
IDENTITY "-" means no certificate of one's own.
"""

from __future__ import annotations

import json
import signal
import sys
import threading
import time

import zenoh

from skelfuse.config import load_rig_config, zenoh_config
from skelfuse.wire import keys

FORGED = b"forged-by-probe"


def main() -> None:
    command, config, identity, endpoint = sys.argv[1:5]
    cfg = load_rig_config(config)
    conf = zenoh_config(cfg, mode="client", connect=[endpoint], identity=None if identity == "-" else identity)
    if command == "connect":
        try:
            zenoh.open(conf).close()
            print("connected", flush=True)
        except Exception as exc:
            print(f"refused: {str(exc)[:200]}", flush=True)
        return
    session = zenoh.open(conf)
    if command == "forge":
        publishers = [session.declare_publisher(key) for key in sys.argv[5:]]
        for _ in range(20):
            for publisher in publishers:
                publisher.put(FORGED)
            time.sleep(0.02)
        time.sleep(0.5)
        session.close()
        print("forged", flush=True)
        return
    out = open(sys.argv[5], "w", encoding="utf-8")
    lock = threading.Lock()
    stop = threading.Event()

    def record(sample: zenoh.Sample) -> None:
        line = json.dumps({"t": time.monotonic(), "key": str(sample.key_expr), "hex": sample.payload.to_bytes().hex()})
        with lock:
            out.write(line + "\n")
            out.flush()

    session.declare_subscriber(keys.all_sensor_skeletons(cfg.name), record)
    session.declare_subscriber(keys.fused_skeletons(cfg.name), record)
    session.declare_subscriber(keys.all_status(cfg.name), record)
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    print("listening", flush=True)
    stop.wait()
    session.close()
    with lock:
        out.close()


if __name__ == "__main__":
    main()
