"""API keys on a real SQLite database: hashed storage, revocation, admin key rotation."""

from __future__ import annotations

import pytest
import sqlalchemy as sa

from farfield.core.errors import AuthError
from farfield.service.db import Database
from farfield.service.keys import authenticate, create_key, ensure_admin_key, revoke_key


@pytest.fixture
def db(tmp_path):
    database = Database(f"sqlite:///{tmp_path / 'keys.db'}")
    database.migrate()
    return database


def test_keys_are_stored_hashed_and_revocable(db):
    key, prefix = create_key(db, "acme")
    tenant = authenticate(db, key)
    with db.engine.connect() as connection:
        stored = connection.execute(sa.text("SELECT prefix, digest FROM api_keys")).all()
    assert all(key not in row.digest for row in stored) and prefix in [row.prefix for row in stored]
    assert authenticate(db, create_key(db, "acme")[0]) == tenant
    revoke_key(db, prefix)
    with pytest.raises(AuthError, match="invalid API key"):  # one message for revoked and unknown keys
        authenticate(db, key)
    with pytest.raises(AuthError, match="invalid API key"):
        authenticate(db, key[:-1] + ("x" if key[-1] != "x" else "y"))


def test_a_new_admin_key_rotates_the_old_one(db):
    first, second = "ff_admin_first-secret", "ff_admin_second-secret"  # same visible prefix "admin"
    ensure_admin_key(db, first)
    admin = authenticate(db, first)
    ensure_admin_key(db, first)  # restarting with the same key changes nothing
    assert authenticate(db, first) == admin
    ensure_admin_key(db, second)
    assert authenticate(db, second) == admin
    with pytest.raises(AuthError, match="invalid API key"):  # one message for revoked and unknown keys
        authenticate(db, first)
    key, _ = create_key(db, "admin")  # keys made with `farfield keys create` are not bootstrap keys
    ensure_admin_key(db, first)  # going back re-enables the first and revokes the second
    assert authenticate(db, first) == admin and authenticate(db, key) == admin
    with pytest.raises(AuthError, match="invalid API key"):  # one message for revoked and unknown keys
        authenticate(db, second)
