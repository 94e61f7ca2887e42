"""Layered environment-map impostors (seed 002): the technique (``technique``), its layer arrangement
(``arrangement``), gap filling (``gap_fill``), near field (``near_field``) and reference runtime
(``runtime``)."""

from farfield.core.techniques.envmap.technique import TECHNIQUE

__all__ = ["TECHNIQUE"]
