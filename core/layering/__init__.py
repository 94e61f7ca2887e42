"""The layer pipeline that layered impostors, environment-map faces and textured depth meshes share:
the layer plan (``plan``), the gap-free recording (``recording``), culling (``culling``, ``culled``),
box-grown quads (``quads``), tiles (``tiles``) and atlas pages (``atlas``)."""
