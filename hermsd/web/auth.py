"""Who may change the tun from the page: logins, sessions, CSRF tokens, login rate limits.

Pure bookkeeping, time passed in (the server gives `time.monotonic()`), so tests step it.
A session is a random id (256 bits) in an HttpOnly, SameSite=Strict cookie, kept only in
this process's memory (a restart logs everyone out), ended after `lifetime` seconds
without use. Each session has its own CSRF token, which every change must carry in a
header: a cross-site page can neither read it nor, with SameSite=Strict, send the cookie.

Wrong passwords are limited twice, as token buckets: per client address (LOGIN_BURST at
once, then one per LOGIN_REFILL_S) and for everyone together (GLOBAL_BURST, one per
GLOBAL_REFILL_S), so that neither one client nor many can guess at speed; each scrypt
check also costs 16 MiB and tens of ms, which the global bucket bounds. An attempt takes
its token before the check (so a burst of guesses cannot all start at once) and a right
password gives it back.
"""

from __future__ import annotations

import secrets
from dataclasses import dataclass

LOGIN_BURST = 5
LOGIN_REFILL_S = 60.0
GLOBAL_BURST = 20
GLOBAL_REFILL_S = 6.0
MAX_SESSIONS = 64  # the oldest is ended beyond this
MAX_CLIENTS_TRACKED = 1024  # per-client buckets kept; the fullest are forgotten first


@dataclass(slots=True)
class Session:
    csrf: str
    last_used: float


@dataclass(slots=True)
class _Bucket:
    tokens: float
    at: float


class TokenBucket:
    """`burst` attempts at once, refilled at one per `refill_s` seconds."""

    def __init__(self, burst: int, refill_s: float) -> None:
        self.burst = burst
        self.refill_s = refill_s

    def level(self, bucket: _Bucket, now: float) -> float:
        return min(self.burst, bucket.tokens + (now - bucket.at) / self.refill_s)

    def wait(self, bucket: _Bucket, now: float) -> float:
        """Seconds until an attempt may go ahead (0: now)."""
        return max(0.0, 1.0 - self.level(bucket, now)) * self.refill_s

    def take(self, bucket: _Bucket, now: float) -> None:
        bucket.tokens, bucket.at = self.level(bucket, now) - 1.0, now

    def give_back(self, bucket: _Bucket, now: float) -> None:
        bucket.tokens, bucket.at = min(self.burst, self.level(bucket, now) + 1.0), now


class LoginLimiter:
    """Login attempts per client address and overall."""

    def __init__(self) -> None:
        self._per_client = TokenBucket(LOGIN_BURST, LOGIN_REFILL_S)
        self._overall = TokenBucket(GLOBAL_BURST, GLOBAL_REFILL_S)
        self._clients: dict[str, _Bucket] = {}
        self._all = _Bucket(GLOBAL_BURST, 0.0)

    def attempt(self, client: str, now: float) -> float:
        """0 when `client` may try a password now (counted), else the seconds to wait."""
        if len(self._clients) >= MAX_CLIENTS_TRACKED and client not in self._clients:
            self._forget_rested(now)
        bucket = self._clients.setdefault(client, _Bucket(LOGIN_BURST, now))
        wait = max(self._per_client.wait(bucket, now), self._overall.wait(self._all, now))
        if wait > 0.0:
            return wait
        self._per_client.take(bucket, now)
        self._overall.take(self._all, now)
        return 0.0

    def succeeded(self, client: str, now: float) -> None:
        """The attempt had the right password: it does not count against anyone."""
        bucket = self._clients.get(client)
        if bucket is not None:
            self._per_client.give_back(bucket, now)
        self._overall.give_back(self._all, now)

    def _forget_rested(self, now: float) -> None:
        """Drop the buckets that have refilled (they hold nothing); if none has, the fullest."""
        full = [
            c for c, b in self._clients.items() if self._per_client.level(b, now) >= LOGIN_BURST
        ]
        for client in full or [max(self._clients, key=lambda c: self._clients[c].tokens)]:
            del self._clients[client]


class Sessions:
    """The logged-in sessions of this process."""

    def __init__(self, lifetime: float) -> None:
        self.lifetime = lifetime
        self._sessions: dict[str, Session] = {}

    def create(self, now: float) -> tuple[str, Session]:
        if len(self._sessions) >= MAX_SESSIONS:
            oldest = min(self._sessions, key=lambda sid: self._sessions[sid].last_used)
            del self._sessions[oldest]
        sid = secrets.token_urlsafe(32)
        session = Session(secrets.token_urlsafe(32), now)
        self._sessions[sid] = session
        return sid, session

    def find(self, sid: str | None, now: float) -> Session | None:
        """The live session of cookie value `sid` (its use noted), or None."""
        if not sid:
            return None
        session = self._sessions.get(sid)
        if session is None:
            return None
        if now - session.last_used > self.lifetime:
            del self._sessions[sid]
            return None
        session.last_used = now
        return session

    def end(self, sid: str | None) -> None:
        if sid:
            self._sessions.pop(sid, None)


def csrf_matches(session: Session, token: str | None) -> bool:
    return token is not None and secrets.compare_digest(session.csrf, token)
