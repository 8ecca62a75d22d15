"""Which failures are worth another attempt."""

from __future__ import annotations

from sqlalchemy.exc import DBAPIError, OperationalError

from contract.errors import TransientJobError


def is_transient(exc: BaseException) -> bool:
    """A passing fault: the handler said so, the network or the database was away."""
    if isinstance(exc, TransientJobError | ConnectionError | TimeoutError):
        return True
    if isinstance(exc, OperationalError):
        return True
    return isinstance(exc, DBAPIError) and bool(exc.connection_invalidated)
