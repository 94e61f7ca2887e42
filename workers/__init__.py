"""Celery application and render tasks.

Empty until the service issue lands; each task will load a cell by id, call one ``core``
pipeline function and store what it returns.
"""
