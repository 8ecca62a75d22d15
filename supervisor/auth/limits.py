"""Keeping sign-in from being used against the API.

A sign-in checks a password with argon2id (64 MiB, about half a second of one core), so
unbounded anonymous sign-ins starve every other request. Three guards:

- rate limits, per API process: failed sign-ins per account and sign-in attempts per
  client address in a sliding minute; past either, 429 with ``Retry-After`` before any
  password is checked;
- password-check slots shared by every API process of the machine (``sign_in_concurrency``
  lock files in the data folder, held with ``flock``, released by the kernel if a process
  dies): at most that many argon2 checks run at once however many processes serve, and a
  sign-in that would wait behind more than ``QUEUE_PER_SLOT`` others is turned away;
- a refused sign-in is answered after ``REFUSAL_DELAY_S`` (an idle wait, no thread), so a
  client that ignores ``Retry-After`` floods nothing but its own connection.
"""

from __future__ import annotations

import asyncio
import fcntl
import math
import os
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

WINDOW_S = 60.0
QUEUE_PER_SLOT = 4
"""Sign-ins that may wait for each password-check slot before new ones are refused."""
SLOT_POLL_S = 0.02
REFUSAL_DELAY_S = 1.0


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


class PasswordSlots:
    """``count`` lock files: holding one is the right to run one password check."""

    def __init__(self, folder: Path, count: int) -> None:
        folder.mkdir(mode=0o700, parents=True, exist_ok=True)
        self.count = count
        self._fds = [
            os.open(folder / f"slot-{i}.lock", os.O_RDWR | os.O_CREAT, 0o600) for i in range(count)
        ]
        self._free = list(self._fds)  # this process's fds not held by one of its own checks

    def try_take(self) -> int | None:
        for fd in list(self._free):
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                continue
            self._free.remove(fd)
            return fd
        return None

    def give_back(self, fd: int) -> None:
        fcntl.flock(fd, fcntl.LOCK_UN)
        self._free.append(fd)


class SignInGuard:
    def __init__(
        self, *, per_account: int, per_address: int, concurrency: int, slot_folder: Path
    ) -> None:
        self.failures = SlidingWindow(per_account)
        self.attempts = SlidingWindow(per_address)
        self.slots = PasswordSlots(slot_folder, concurrency)
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
        if self._waiting >= self.slots.count * QUEUE_PER_SLOT:
            raise TooManySignIns("Too many sign-ins at once", 1.0)
        self.attempts.add(address, now)

    def failed(self, username: str) -> None:
        self.failures.add(username.lower(), time.monotonic())

    async def slot(self) -> int:
        """Wait (idle, polling) for a password-check slot; give it back with ``release``."""
        self._waiting += 1
        try:
            while (fd := self.slots.try_take()) is None:
                await asyncio.sleep(SLOT_POLL_S)
            return fd
        finally:
            self._waiting -= 1

    def release(self, fd: int) -> None:
        self.slots.give_back(fd)
