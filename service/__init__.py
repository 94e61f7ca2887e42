"""The service's shared parts: settings, the SQL job database, the blob store, embedded Redis.

``api`` (HTTP routes) and ``workers`` (Celery tasks) both build on this package; it builds on
``core`` and imports neither of them.  Nothing here knows about HTTP.
"""
