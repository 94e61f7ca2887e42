"""Textured depth meshes (seed 003): the technique (``technique``), its voxel field, covering mesh,
simplification, chart textures and mask atlas."""

from farfield.core.techniques.tdm.technique import TECHNIQUE

__all__ = ["TECHNIQUE"]
