"""The service's shared parts: settings, the SQL job database, the blob store, embedded Redis; jobs and placement jobs.

``api`` (HTTP routes) and ``workers`` (Celery tasks) both build on this package; it builds on
``core`` and imports neither of them.  Nothing here knows about HTTP.  Its two packages of job
logic: :mod:`farfield.service.jobs` (schema, admission, the cell state machine, records, the index) builds on
:mod:`farfield.service.placement` (the placement-algorithm registry, the lease, the rounds), which builds
on neither ``farfield.service.jobs`` nor anything above it (tests/test_import_graph.py).
"""
