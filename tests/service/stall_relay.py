"""A TCP relay that stops reading on command: a link that fills for sure, for tests of slow subscribers.

A subscriber that is SIGSTOPped does not always congest its publisher's link: the kernel may have grown the
socket buffers (loopback autotuning) or the subscriber's zenoh threads may have read the bytes just before the
stop. Between a publisher's listener and a subscriber this relay forwards both directions; :meth:`pause` makes
it stop reading the publisher's side at once, so, with a small receive buffer on that socket (set before
connecting, so TCP's window stays small), what the publisher sends fills the kernel's buffers within a few
tens of KB, on an idle machine as on a loaded one. :meth:`resume` reads again. The other direction always
flows. In-process (threads), closed with :meth:`close`.
"""

from __future__ import annotations

import contextlib
import select
import socket
import threading

RELAY_RCVBUF = 4096
"""Receive buffer (bytes) of the relay's socket to the publisher; Linux doubles it."""


class StallRelay:
    """Relay ``127.0.0.1:port`` (a subscriber connects here) to ``127.0.0.1:target_port`` (the publisher).

    Parameters
    ----------
    target_port : int
        The publisher's zenoh listener.
    rcvbuf : int
        SO_RCVBUF of the socket to the publisher, bytes.
    """

    def __init__(self, target_port: int, *, rcvbuf: int = RELAY_RCVBUF) -> None:
        self.target_port = int(target_port)
        self.rcvbuf = int(rcvbuf)
        self._reading = threading.Event()
        self._reading.set()
        self._closed = threading.Event()
        self._sockets: list[socket.socket] = []
        self._lock = threading.Lock()
        self.forwarded = 0  # bytes from the publisher to the subscriber
        self._listener = socket.create_server(("127.0.0.1", 0))
        self._listener.settimeout(0.1)
        self.port = int(self._listener.getsockname()[1])
        self._threads = [threading.Thread(target=self._accept, name="stall-relay-accept", daemon=True)]
        self._threads[0].start()

    def pause(self) -> None:
        """Stop reading from the publisher (its bytes stay in the kernel's buffers until :meth:`resume`)."""
        self._reading.clear()

    def resume(self) -> None:
        self._reading.set()

    def close(self) -> None:
        self._closed.set()
        self._reading.set()
        with self._lock:
            sockets, self._sockets = self._sockets, []
        for sock in [self._listener, *sockets]:
            with contextlib.suppress(OSError):
                sock.close()
        for thread in self._threads:
            thread.join(2.0)

    def _accept(self) -> None:
        while not self._closed.is_set():
            try:
                downstream, _ = self._listener.accept()
            except (TimeoutError, OSError):
                continue
            upstream = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            upstream.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, self.rcvbuf)  # before connect: small window
            try:
                upstream.connect(("127.0.0.1", self.target_port))
            except OSError:
                downstream.close()
                upstream.close()
                continue
            with self._lock:
                self._sockets += [downstream, upstream]
            for src, dst, gated in ((upstream, downstream, True), (downstream, upstream, False)):
                thread = threading.Thread(target=self._pump, args=(src, dst, gated), name="stall-relay", daemon=True)
                self._threads.append(thread)
                thread.start()

    def _pump(self, src: socket.socket, dst: socket.socket, gated: bool) -> None:
        try:
            while not self._closed.is_set():
                if gated and not self._reading.wait(0.1):
                    continue
                readable, _, _ = select.select([src], [], [], 0.1)  # closed: ValueError (fd -1)
                if not readable or (gated and not self._reading.is_set()):
                    continue
                data = src.recv(65536)
                if not data:
                    break
                dst.sendall(data)
                if gated:
                    self.forwarded += len(data)
        except (OSError, ValueError):  # closed under it
            pass
        finally:
            for sock in (src, dst):
                with contextlib.suppress(OSError):
                    sock.shutdown(socket.SHUT_RDWR)
