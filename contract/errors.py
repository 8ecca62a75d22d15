"""Exceptions a job handler raises to say how its attempt ended."""

from __future__ import annotations


class JobCancelled(Exception):
    """Raised inside a handler (by ``JobContext.progress``) once cancellation was asked."""


class JobTimeLimit(Exception):
    """Raised inside a handler once the attempt ran past the configured time limit."""


class JobLost(Exception):
    """Raised inside a handler when another worker has taken the job over."""


class TransientJobError(Exception):
    """A failure worth retrying (a resource briefly unavailable); retried with backoff."""


class JobInputError(Exception):
    """The job's inputs cannot be processed; the job fails at once with this message."""
