"""The Celery side of the service: :mod:`farfield.workers.app` (the application, its broker settings
and the one ``render`` queue) and :mod:`farfield.workers.tasks` (bake a cell, plan and check a
placement job), each task a few lines around a function of :mod:`farfield.service`.
"""
