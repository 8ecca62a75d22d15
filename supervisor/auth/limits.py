"""Keeping sign-in from being used against the API.

A sign-in checks a password with argon2 (64 MiB, about half a second of one core), so
unbounded anonymous sign-ins starve every other request. Two guards, per API process:

- rate limits: failed sign-ins per account and sign-in attempts per client address in a
  sliding minute; past either, 429 with ``Retry-After`` before any password is checked;
- a bound on password checks running at once (``sign_in_concurrency``) and on those
  waiting for their turn: a sign-in that would wait in a long queue is answered 429 at
  once instead of piling up threads.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections import deque
from dataclasses import dataclass, field

WINDOW_S = 60.0
QUEUE_PER_SLOT = 4
"""Sign-ins that may wait for each password-check slot before new ones are refused."""


@dataclass
class SlidingWindow:
    """Events per key in the last ``window_s`` seconds."""

    limit: int
    window_s: float = WINDOW_S
    _events: dict[str, deque[float]] = field(default_factory=dict)

    def _recent(self, key: str, now: float) -> deque[float]:
        events = self._events.setdefault(key, deque())
        while events and events[0] <= now - self.window_s:
            events.popleft()
        if not events:
            self._events.pop(key, None)
        return events

    def retry_after_s(self, key: str, now: float) -> float:
        """0 when another event is allowed, else seconds until one is."""
        events = self._recent(key, now)
        if len(events) < self.limit:
            return 0.0
        return events[0] + self.window_s - now

    def add(self, key: str, now: float) -> None:
        self._recent(key, now)
        self._events.setdefault(key, deque()).append(now)
        if len(self._events) > 100_000:  # a flood of distinct keys: forget the oldest half
            for stale in list(self._events)[:50_000]:
                del self._events[stale]


class TooManySignIns(Exception):
    def __init__(self, reason: str, retry_after_s: float) -> None:
        super().__init__(reason)
        self.reason = reason
        self.retry_after_s = max(1, math.ceil(retry_after_s))


class SignInGuard:
    def __init__(self, *, per_account: int, per_address: int, concurrency: int) -> None:
        self.failures = SlidingWindow(per_account)
        self.attempts = SlidingWindow(per_address)
        self.concurrency = concurrency
        self._slots: asyncio.Semaphore | None = None
        self._waiting = 0

    def admit(self, *, username: str, address: str) -> None:
        """Raises ``TooManySignIns`` when this sign-in must not be tried now."""
        now = time.monotonic()
        wait_s = self.attempts.retry_after_s(address, now)
        if wait_s > 0:
            raise TooManySignIns(
                f"Too many sign-ins from {address} ({self.attempts.limit} a minute)", wait_s
            )
        wait_s = self.failures.retry_after_s(username.lower(), now)
        if wait_s > 0:
            raise TooManySignIns(
                f"Too many failed sign-ins for {username!r} ({self.failures.limit} a minute)",
                wait_s,
            )
        if self._waiting >= self.concurrency * QUEUE_PER_SLOT:
            raise TooManySignIns("Too many sign-ins at once", 1.0)
        self.attempts.add(address, now)

    def failed(self, username: str) -> None:
        self.failures.add(username.lower(), time.monotonic())

    async def __aenter__(self) -> None:
        if self._slots is None:  # made in the event loop that uses it
            self._slots = asyncio.Semaphore(self.concurrency)
        self._waiting += 1
        try:
            await self._slots.acquire()
        finally:
            self._waiting -= 1

    async def __aexit__(self, *exc: object) -> None:
        assert self._slots is not None
        self._slots.release()
