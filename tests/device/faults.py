"""A TCP proxy that damages the byte stream between host and device, frame by frame.

It sits on a real socket between ``DeviceClient`` (``socket://``) and the device service's
TCP link, splits each direction on the frame delimiter and, with seeded probabilities,
drops a frame, sends it twice, flips one bit, cuts it short, stalls the stream, or inserts
a burst of random bytes (zeros included).
"""

from __future__ import annotations

import asyncio
import contextlib
import random
from collections import Counter
from dataclasses import dataclass


@dataclass
class Faults:
    drop: float = 0.0
    duplicate: float = 0.0
    flip: float = 0.0
    truncate: float = 0.0
    stall: float = 0.0
    """Probability of holding the stream for 20-60 ms before a frame."""
    garbage: float = 0.0
    """Probability of a 1-200 byte burst of random bytes before a frame."""


class FaultProxy:
    def __init__(self, upstream: tuple[str, int], faults: Faults, seed: int = 0) -> None:
        self.upstream = upstream
        self.faults = faults
        self.rng = random.Random(seed)
        self.counts: Counter[str] = Counter()
        self._server: asyncio.Server | None = None
        self._tasks: set[asyncio.Task[None]] = set()
        self.port = 0

    async def start(self) -> str:
        self._server = await asyncio.start_server(self._serve, "127.0.0.1", 0)
        self.port = self._server.sockets[0].getsockname()[1]
        return f"socket://127.0.0.1:{self.port}"

    async def close(self) -> None:
        if self._server is not None:
            self._server.close()
        for task in list(self._tasks):
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        up_reader, up_writer = await asyncio.open_connection(*self.upstream)
        for src, dst in ((reader, up_writer), (up_reader, writer)):
            task = asyncio.create_task(self._pump(src, dst))
            self._tasks.add(task)
            task.add_done_callback(self._tasks.discard)

    async def _pump(self, src: asyncio.StreamReader, dst: asyncio.StreamWriter) -> None:
        pending = b""
        try:
            while data := await src.read(4096):
                pending += data
                *frames, pending = pending.split(b"\x00")
                for frame in frames:
                    await self._forward(frame + b"\x00", dst)
                await dst.drain()
        finally:
            dst.close()

    async def _forward(self, frame: bytes, dst: asyncio.StreamWriter) -> None:
        f, rng = self.faults, self.rng
        if rng.random() < f.stall:
            self.counts["stall"] += 1
            await dst.drain()
            await asyncio.sleep(rng.uniform(0.02, 0.06))
        if rng.random() < f.garbage:
            self.counts["garbage"] += 1
            dst.write(rng.randbytes(rng.randint(1, 200)))
        if rng.random() < f.drop:
            self.counts["drop"] += 1
            return
        if rng.random() < f.flip:
            self.counts["flip"] += 1
            damaged = bytearray(frame)
            bit = rng.randrange((len(frame) - 1) * 8)  # not the delimiter
            damaged[bit // 8] ^= 1 << (bit % 8)
            frame = bytes(damaged)
        elif rng.random() < f.truncate and len(frame) > 2:
            self.counts["truncate"] += 1
            frame = frame[: rng.randrange(1, len(frame) - 1)]  # the next frame ends it
        dst.write(frame)
        if rng.random() < f.duplicate:
            self.counts["duplicate"] += 1
            dst.write(frame)
