"""HTTP API (FastAPI): routes, auth and the dashboard.

Routes only validate, authorise and call ``service`` / ``core``; :func:`api.app.create_app` builds
the application for one :class:`service.settings.Settings`.
"""
