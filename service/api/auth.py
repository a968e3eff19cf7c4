"""Who is calling: the lab of a bearer key, and a limit on failed attempts per client address.

Keys are 256-bit random, so guessing one is hopeless; the limit keeps a client that sends
unknown keys from costing a database lookup each (1200 in a row got 1200 answers). An address
with ``auth_failures`` unknown keys in ``auth_failure_window_s`` gets 429 for the rest of that
window, whatever key it sends: were a valid key still let through, 429 against 200 would tell a
guess that failed from one that hit.
"""

from __future__ import annotations

import threading
import time
from collections import OrderedDict
from functools import lru_cache

from fastapi import HTTPException, status
from sqlalchemy.orm import Session

from service.labs import lab_for_key
from service.models import Lab
from service.settings import get_settings

# Addresses remembered at once: ~200 bytes each, so the table stays under ~2 MB. The least
# recently failing address is forgotten first (a client with more addresses than this can cycle
# through them: the limit is against a careless or scripted client, not a botnet).
MAX_ADDRESSES = 10_000
CHALLENGE = {"WWW-Authenticate": "Bearer"}


class FailureLimiter:
    """Failed authentications per address in a fixed window, for at most ``capacity`` addresses."""

    def __init__(self, allowed: int, window_s: float, capacity: int = MAX_ADDRESSES) -> None:
        self.allowed, self.window_s, self.capacity = allowed, window_s, capacity
        self._failures: OrderedDict[str, tuple[float, int]] = OrderedDict()  # address: (window start, count)
        self._lock = threading.Lock()  # sync dependencies run in a thread pool

    def retry_after(self, address: str) -> int | None:
        """Whole seconds until ``address`` may try again; None if it is not over the limit."""
        with self._lock:
            start, count = self._failures.get(address, (0.0, 0))
        left = start + self.window_s - time.monotonic()
        return max(1, int(left + 0.999)) if count >= self.allowed and left > 0 else None

    def failed(self, address: str) -> None:
        """Count one failure of ``address``."""
        now = time.monotonic()
        with self._lock:
            start, count = self._failures.pop(address, (now, 0))
            if now - start >= self.window_s:
                start, count = now, 0
            self._failures[address] = (start, count + 1)
            while len(self._failures) > self.capacity:
                self._failures.popitem(last=False)


@lru_cache(maxsize=1)
def failure_limiter() -> FailureLimiter:
    """The process's limiter (each API process counts its own clients' failures)."""
    settings = get_settings()
    return FailureLimiter(settings.auth_failures, settings.auth_failure_window_s)


def bearer_token(authorization: str | None) -> str | None:
    """The key of an ``Authorization: Bearer <key>`` header, None for anything else."""
    scheme, _, token = (authorization or "").partition(" ")
    return token.strip() or None if scheme.lower() == "bearer" else None


def authenticate(session: Session, token: str | None, address: str | None) -> Lab:
    """The lab whose key ``token`` is; 401 without a valid key, 429 for an address over the limit."""
    limiter, address = failure_limiter(), address or "unknown"
    if (wait := limiter.retry_after(address)) is not None:
        raise HTTPException(status.HTTP_429_TOO_MANY_REQUESTS,
                            f"too many unknown API keys from this address; try again in {wait} s",
                            {"Retry-After": str(wait)})
    if token is None:
        raise HTTPException(status.HTTP_401_UNAUTHORIZED,
                            "send the lab's API key as 'Authorization: Bearer <key>'", CHALLENGE)
    lab = lab_for_key(session, token)
    if lab is None:
        limiter.failed(address)
        raise HTTPException(status.HTTP_401_UNAUTHORIZED, "unknown API key", CHALLENGE)
    return lab
