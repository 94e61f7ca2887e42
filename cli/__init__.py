"""The ``farfield`` command line: thin commands that call ``core`` and print text or ``--json``."""
