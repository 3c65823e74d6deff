#!/usr/bin/env python3
"""A TCP relay that delays every byte by a fixed time in each direction: the stand-in for
`tc netem delay` on a kernel without netem (scripts/bench-remote.sh). Order is kept; each
chunk is written when its delay has passed since it was read.

    python3 scripts/delay-relay.py LISTEN_HOST:PORT TARGET_HOST:PORT DELAY_MS

Standard library only. Runs until killed.
"""

from __future__ import annotations

import asyncio
import sys
import time


async def pump(reader: asyncio.StreamReader, writer: asyncio.StreamWriter, delay_s: float) -> None:
    queue: asyncio.Queue = asyncio.Queue()

    async def read() -> None:
        while True:
            chunk = await reader.read(65536)
            await queue.put((time.monotonic() + delay_s, chunk))
            if not chunk:
                return

    async def write() -> None:
        while True:
            due, chunk = await queue.get()
            wait = due - time.monotonic()
            if wait > 0:
                await asyncio.sleep(wait)
            if not chunk:
                writer.close()
                return
            writer.write(chunk)
            await writer.drain()

    await asyncio.gather(read(), write(), return_exceptions=True)


def split(addr: str) -> tuple[str, int]:
    host, _, port = addr.rpartition(":")
    if not host or not port.isdigit():
        raise SystemExit(f"`{addr}` is not HOST:PORT")
    return host, int(port)


async def main(listen: str, target: str, delay_ms: float) -> None:
    if not delay_ms >= 0:
        raise SystemExit(f"delay `{delay_ms}` ms: must be a number of milliseconds, at least 0")
    (lh, lp), (th, tp) = split(listen), split(target)
    delay_s = delay_ms / 1000.0

    async def serve(r: asyncio.StreamReader, w: asyncio.StreamWriter) -> None:
        try:
            tr, tw = await asyncio.open_connection(th, tp)
        except OSError as e:
            print(f"delay-relay: cannot reach {target}: {e}", file=sys.stderr)
            w.close()
            return
        await asyncio.gather(pump(r, tw, delay_s), pump(tr, w, delay_s))

    server = await asyncio.start_server(serve, lh, lp)
    async with server:
        await server.serve_forever()


if __name__ == "__main__":
    if len(sys.argv) != 4:
        raise SystemExit(__doc__)
    try:
        asyncio.run(main(sys.argv[1], sys.argv[2], float(sys.argv[3])))
    except KeyboardInterrupt:
        pass
