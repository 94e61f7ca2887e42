"""Automatic impostor placement for a frame-time or primitive budget at minimum memory (seed 000 ch. 5).

object hierarchy (§5.4) -> problem view space (§5.5) -> candidates (§5.6) -> greedy choice with
lazy re-ranking (§5.7) -> :class:`~farfield.core.placement.result.Placement`.
"""
