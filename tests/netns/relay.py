"""A userspace TCP relay that delays and stalls one link (this kernel has no netem).

``python relay.py LISTEN_HOST LISTEN_PORT TARGET_HOST TARGET_PORT DELAY_MS STALL_PROB STALL_MS SEED``

Every chunk read from either side is forwarded after ``DELAY_MS``; with probability ``STALL_PROB`` a chunk
is held ``STALL_MS`` longer, and the chunks behind it wait too (order is kept): what a lost TCP segment
and its retransmission look like to the application. Runs until killed.
"""

from __future__ import annotations

import asyncio
import random
import sys


async def pump(
    reader: asyncio.StreamReader,
    writer: asyncio.StreamWriter,
    delay_s: float,
    stall_p: float,
    stall_s: float,
    rng: random.Random,
) -> None:
    loop = asyncio.get_running_loop()
    queue: asyncio.Queue[tuple[float, bytes]] = asyncio.Queue()

    async def send() -> None:
        while True:
            due, chunk = await queue.get()
            wait = due - loop.time()
            if wait > 0:
                await asyncio.sleep(wait)
            if not chunk:
                writer.close()
                return
            writer.write(chunk)
            await writer.drain()

    sender = asyncio.create_task(send())
    last_due = 0.0
    try:
        while True:
            chunk = await reader.read(65536)
            due = loop.time() + delay_s + (stall_s if rng.random() < stall_p else 0.0)
            last_due = max(last_due, due)  # order kept: a stalled chunk holds back the ones behind it
            await queue.put((last_due, chunk))
            if not chunk:
                break
    finally:
        await sender


async def main() -> None:
    host, port, target_host, target_port = sys.argv[1], int(sys.argv[2]), sys.argv[3], int(sys.argv[4])
    delay_s, stall_p, stall_s = float(sys.argv[5]) / 1000, float(sys.argv[6]), float(sys.argv[7]) / 1000
    rng = random.Random(int(sys.argv[8]))

    async def handle(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            up_reader, up_writer = await asyncio.open_connection(target_host, target_port)
        except OSError:
            writer.close()
            return
        await asyncio.gather(
            pump(reader, up_writer, delay_s, stall_p, stall_s, rng),
            pump(up_reader, writer, delay_s, stall_p, stall_s, rng),
            return_exceptions=True,
        )

    server = await asyncio.start_server(handle, host, port)
    async with server:
        await server.serve_forever()


if __name__ == "__main__":
    asyncio.run(main())
