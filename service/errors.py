"""Errors the service layer raises; the API turns them into JSON ``{"detail": ...}``."""

from __future__ import annotations


class NotFoundError(LookupError):
    """A resource that does not exist or belongs to another lab (the two look the same: 404)."""


class ConflictError(RuntimeError):
    """A request that the resource's state does not allow now (409), e.g. results not ready."""


class InvalidError(ValueError):
    """A request that names things that do not fit together (422)."""


class QueueUnavailableError(RuntimeError):
    """The broker could not take a job's task (503); the job was failed, not left queued."""


class RateLimitedError(RuntimeError):
    """A lab over one of its limits (429); ``retry_after`` seconds until it may try again."""

    def __init__(self, message: str, retry_after: int) -> None:
        super().__init__(message)
        self.retry_after = max(1, retry_after)
