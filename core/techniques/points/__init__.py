"""Point-based impostors (seed 001): the technique (``technique``), where it samples a part
(``sampling``), its points (``samples``) and their directional colours (``appearance``)."""

from farfield.core.techniques.points.technique import TECHNIQUE

__all__ = ["TECHNIQUE"]
