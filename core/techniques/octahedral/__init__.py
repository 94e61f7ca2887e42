"""Octahedral impostors: the technique (``technique``), the octahedral map (``mapping``), the
frames and their atlas (``frames``), the payload (``payload``), the reference runtime
(``runtime``) and the accuracy distance (``accuracy``); docs/techniques/octahedral.md."""

from farfield.core.techniques.octahedral.technique import TECHNIQUE

__all__ = ["TECHNIQUE"]
