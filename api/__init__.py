"""HTTP API (FastAPI): routes, request/response schemas, auth and the dashboard.

Empty until the service issue lands; routes will only validate, authorise and call ``core``.
"""
