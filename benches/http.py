"""A tiny keep-alive HTTP/1.1 client for load generation on one event loop."""

from __future__ import annotations

import asyncio
import socket
from collections.abc import Callable, Coroutine
from contextlib import suppress
from typing import Any


class RawHttp:
    """One keep-alive HTTP/1.1 connection, just enough for JSON requests to uvicorn.

    httpx costs several times more CPU per request; on a 2-core machine that CPU would
    come out of the server being measured."""

    def __init__(
        self, host: str, port: int, token: str | None, *, local_address: str | None = None
    ) -> None:
        self.host, self.port = host, port
        self.local_address = local_address
        """Connect from this address (a loopback client of its own: 127.0.0.x)."""
        bearer = f"Authorization: Bearer {token}\r\n" if token else ""
        self._static = f"Host: {host}:{port}\r\n{bearer}Accept: application/json\r\n"
        self._reader: asyncio.StreamReader | None = None
        self._writer: asyncio.StreamWriter | None = None

    async def connect(self) -> None:
        local = (self.local_address, 0) if self.local_address else None
        self._reader, self._writer = await asyncio.open_connection(
            self.host, self.port, local_addr=local
        )
        sock = self._writer.get_extra_info("socket")
        if sock is not None:
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

    async def close(self) -> None:
        writer, self._reader, self._writer = self._writer, None, None
        if writer is not None:
            writer.close()
            with suppress(OSError):
                await writer.wait_closed()

    async def request(self, method: str, path: str, body: bytes | None = None) -> tuple[int, bytes]:
        if self._writer is None:
            await self.connect()
        assert self._reader is not None and self._writer is not None
        head = f"{method} {path} HTTP/1.1\r\n{self._static}"
        if body is not None:
            head += f"Content-Type: application/json\r\nContent-Length: {len(body)}\r\n"
        self._writer.write(head.encode() + b"\r\n" + (body or b""))
        status, length, close = await self._read_head(self._reader)
        payload = await self._reader.readexactly(length) if length else b""
        if close:
            await self.close()
        return status, payload

    async def try_request(
        self, method: str, path: str, body: bytes | None = None, *, timeout_s: float
    ) -> tuple[int, bytes]:
        """``request``, or status 0 (and the connection closed) when it fails or times out."""
        try:
            return await asyncio.wait_for(self.request(method, path, body), timeout_s)
        except (OSError, TimeoutError, ValueError, IndexError, asyncio.IncompleteReadError):
            await self.close()
            return 0, b""

    @staticmethod
    async def _read_head(reader: asyncio.StreamReader) -> tuple[int, int, bool]:
        status_line = await reader.readline()
        if not status_line:
            raise ConnectionError("the server closed the connection")
        status = int(status_line.split(b" ", 2)[1])
        length, close = 0, False
        while True:
            line = await reader.readline()
            if line in (b"\r\n", b"\n", b""):
                return status, length, close
            name, _, value = line.partition(b":")
            name = name.strip().lower()
            if name == b"content-length":
                length = int(value)
            elif name == b"connection":
                close = value.strip().lower() == b"close"
            elif name == b"transfer-encoding":
                raise ValueError("chunked responses are not supported by the bench client")


def run_async(coroutine: Coroutine[Any, Any, Any]) -> Any:
    """Run on uvloop when it is installed (less load-generator CPU)."""
    factory: Callable[[], asyncio.AbstractEventLoop] | None = None
    try:
        import uvloop

        factory = uvloop.new_event_loop
    except ImportError:  # pragma: no cover - uvloop comes with uvicorn[standard]
        pass
    with asyncio.Runner(loop_factory=factory) as runner:
        return runner.run(coroutine)
