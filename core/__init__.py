"""farfield core: scenes, view cells, layer mathematics, and (later) the renderer and bundle format.

Nothing in ``core`` imports ``api``, ``workers`` or ``cli``; every function takes plain data
(numpy arrays, frozen dataclasses) and returns plain data.
"""

__version__ = "0.3.1"
