"""HTTP API (FastAPI): routes, auth and the dashboard.

Routes only validate, authorise and call ``service`` / ``core``; :func:`farfield.api.app.create_app` builds
the application for one :class:`farfield.service.settings.Settings`.
"""
