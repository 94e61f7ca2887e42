"""API keys: ``ff_<prefix>_<secret>``, stored as a SHA-256 digest; each key belongs to a tenant."""

from __future__ import annotations

import hashlib
import hmac
import secrets
import uuid

from sqlalchemy import select

from farfield.core.errors import AuthError, NotFoundError
from farfield.service.db import ApiKey, Database, Tenant, now

ADMIN_TENANT = "admin"


def _digest(key: str) -> str:
    return hashlib.sha256(key.encode()).hexdigest()


def _prefix_of(key: str) -> str | None:
    parts = key.split("_")
    return parts[1] if len(parts) == 3 and parts[0] == "ff" and parts[1] and parts[2] else None


def tenant_named(db: Database, name: str, create: bool = True) -> Tenant:
    """The tenant called ``name`` (created when missing and ``create``)."""
    with db.session() as s:
        tenant = s.scalar(select(Tenant).where(Tenant.name == name))
        if tenant is None:
            if not create:
                raise NotFoundError(f"no tenant named {name!r}")
            tenant = Tenant(id=uuid.uuid4().hex, name=name, created_at=now())
            s.add(tenant)
        return tenant


def create_key(db: Database, tenant_name: str) -> tuple[str, str]:
    """A new key for ``tenant_name`` (the tenant is created if new): (key, prefix).  The key is shown once."""
    tenant = tenant_named(db, tenant_name)
    prefix = secrets.token_hex(6)
    key = f"ff_{prefix}_{secrets.token_urlsafe(24).replace('_', '-')}"
    with db.session() as s:
        s.add(ApiKey(id=uuid.uuid4().hex, tenant_id=tenant.id, prefix=prefix, digest=_digest(key), created_at=now()))
    return key, prefix


BOOTSTRAP = "bootstrap-"  # prefix of the admin key from the environment, followed by part of its digest


def _bootstrap_prefix(key: str) -> str:
    return BOOTSTRAP + _digest(key)[:16]


def ensure_admin_key(db: Database, key: str) -> None:
    """Make ``key`` (FARFIELD_ADMIN_KEY, or the one farfield up generates) the bootstrap tenant's
    admin key, and revoke any earlier one: setting a new admin key rotates it."""
    prefix = _bootstrap_prefix(key)
    tenant = tenant_named(db, ADMIN_TENANT)
    with db.session() as s:
        row = s.scalar(select(ApiKey).where(ApiKey.prefix == prefix))
        if row is None:
            s.add(
                ApiKey(id=uuid.uuid4().hex, tenant_id=tenant.id, prefix=prefix, digest=_digest(key), created_at=now())
            )
        elif row.revoked_at is not None:
            row.revoked_at = None  # set again on purpose
        for old in s.scalars(
            select(ApiKey).where(
                ApiKey.prefix.startswith(BOOTSTRAP), ApiKey.prefix != prefix, ApiKey.revoked_at.is_(None)
            )
        ):
            old.revoked_at = now()


def revoke_key(db: Database, prefix: str) -> None:
    with db.session() as s:
        row = s.scalar(select(ApiKey).where(ApiKey.prefix == prefix))
        if row is None:
            raise NotFoundError(f"no API key with prefix {prefix!r}")
        if row.revoked_at is None:
            row.revoked_at = now()


def list_keys(db: Database) -> list[dict]:
    with db.session() as s:
        rows = s.execute(
            select(ApiKey, Tenant.name).join(Tenant, Tenant.id == ApiKey.tenant_id).order_by(ApiKey.created_at)
        ).all()
        return [
            {"prefix": key.prefix, "tenant": name, "created_at": key.created_at, "revoked": key.revoked_at is not None}
            for key, name in rows
        ]


# The one message for a key that does not authenticate, unknown or revoked alike: telling them apart
# tells a guesser which prefixes exist (issue 59, item 11).
INVALID_KEY = "invalid API key"


def bearer_key(values: list[str]) -> str | None:
    """The API key of a request's ``Authorization`` header values (every one of them, in order): the
    one place that reads credentials, for the upload's early check and every route alike.

    Raises
    ------
    AuthError
        More than one ``Authorization`` header (two readers could take different ones: issue 59,
        item 7), or one whose scheme is not ``Bearer``.

    >>> bearer_key(["Bearer ff_abc "]), bearer_key([])
    ('ff_abc', None)
    """
    if len(values) > 1:
        raise AuthError("send one Authorization header, not several")
    if not values:
        return None
    scheme, _, key = values[0].partition(" ")
    if scheme.lower() != "bearer":
        raise AuthError("use 'Authorization: Bearer <key>'")
    return key.strip() or None


def authenticate(db: Database, key: str | None) -> str:
    """The tenant id of a valid, unrevoked ``key``; :class:`AuthError` otherwise (one message,
    :data:`INVALID_KEY`, for an unknown and a revoked key)."""
    if not key:
        raise AuthError("missing API key: send 'Authorization: Bearer <key>'")
    digest = _digest(key)
    with db.session() as s:
        row = s.scalar(select(ApiKey).where(ApiKey.prefix == _prefix_of(key))) if _prefix_of(key) else None
        if row is None or not hmac.compare_digest(row.digest, digest):
            row = s.scalar(select(ApiKey).where(ApiKey.prefix == _bootstrap_prefix(key)))
    if row is None or not hmac.compare_digest(row.digest, digest) or row.revoked_at is not None:
        raise AuthError(INVALID_KEY)
    return row.tenant_id
