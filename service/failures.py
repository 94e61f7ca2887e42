"""The three classes of failure of a cell's attempt, a placement's plan or check, or a worker task's message.

- **transient**: the infrastructure failed (the database, the broker or Redis, the blob store, any
  OSError, no renderer): worth retrying;
- **bad input**: a :class:`~farfield.core.errors.FarfieldError` of kind BAD_INPUT or MISSING: no retry can help;
- **internal**: a bug (any other exception) or a broken invariant (:class:`~farfield.core.errors.InternalError`).

:func:`farfield.service.jobs.runner.run_cell`, :func:`farfield.service.placement.rounds.run_planning` and the worker
tasks (:mod:`farfield.workers.tasks`) sort their failures with :func:`failure_class`.
"""

from __future__ import annotations

import sys

import redis.exceptions
import sqlalchemy.exc
from kombu.exceptions import OperationalError as BrokerError

from farfield.core.errors import ErrorKind, FarfieldError

# The three classes of failure (see the module docstring).
TRANSIENT, BAD_INPUT, INTERNAL = "transient", "bad input", "internal"
# The database, broker or blob store could not be reached or gave up for now.  Not every DBAPI
# error: ProgrammingError, IntegrityError, DataError and NotSupportedError are a wrong query or a
# broken assumption (internal), unless the connection was lost under them.
TRANSIENT_ERRORS: tuple[type[BaseException], ...] = (
    sqlalchemy.exc.OperationalError, sqlalchemy.exc.InterfaceError, sqlalchemy.exc.InternalError,
    sqlalchemy.exc.DisconnectionError, sqlalchemy.exc.TimeoutError,
    redis.exceptions.ConnectionError, redis.exceptions.TimeoutError, BrokerError,
    OSError,  # the local blob store, scratch files, sockets (ConnectionError, TimeoutError)
)  # fmt: skip


def failure_class(error: BaseException) -> str:
    """:data:`TRANSIENT`, :data:`BAD_INPUT` or :data:`INTERNAL` (see the module docstring).

    >>> failure_class(OSError("disk")), failure_class(ValueError("x")), failure_class(FarfieldError("x"))
    ('transient', 'internal', 'bad input')
    """
    if isinstance(error, FarfieldError):
        if error.kind in (ErrorKind.BAD_INPUT, ErrorKind.MISSING):
            return BAD_INPUT
        return TRANSIENT if error.kind is ErrorKind.RENDERER_UNAVAILABLE else INTERNAL  # CONFLICT etc.: not in a cell
    if isinstance(error, sqlalchemy.exc.DBAPIError) and error.connection_invalidated:
        return TRANSIENT
    botocore = sys.modules.get("botocore.exceptions")  # the S3 blob store's errors, when it is in use
    blob_errors = (botocore.BotoCoreError, botocore.ClientError) if botocore is not None else ()
    return TRANSIENT if isinstance(error, (*TRANSIENT_ERRORS, *blob_errors)) else INTERNAL


def failure_message(error: BaseException, klass: str) -> str:
    """The error recorded on a cell: ``Type: message``, after ``internal error: `` for a bug."""
    text = f"{type(error).__name__}: {error}"
    return f"internal error: {text}" if klass == INTERNAL else text
