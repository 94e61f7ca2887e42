"""An OBJ file without ``vt`` and ``vn``: its faces read in linear time by trimesh.

trimesh's OBJ reader (``trimesh.exchange.obj.load_obj``, 4.12) builds each object-and-material
piece whose faces name no uv and no normal from masks and an inverse index over *all* the file's
vertices (``np.zeros(len(v))``, ``v[mask_v]``): pieces x vertices, so a file of 16,000 small objects
took 4.8 s where 1,000 took 0.13 s.  Faces that name a ``vt`` index take its other branch
(``trimesh.visual.texture.unmerge_faces``), which is linear in the piece.

:func:`paired_indices` writes every corner ``i`` of a file without ``vt``/``vn`` as ``i/i``.  The
file has no ``vt``, so trimesh's ``vt[mask_vt]`` fails and it keeps no uv (it catches that, for
materials without uv), exactly as before; ``unmerge_faces`` of a face array paired with itself
keeps each referenced vertex once, in ascending index order, with the faces renumbered the same,
which is what the mask gave.  So the objects' names, vertices, triangles and materials are the
ones trimesh read before (tests/test_scene.py compares them), in time linear in the file
(docs/measurements/loading.md).
"""

from __future__ import annotations

import re

# A vt or vn statement anywhere, or a face line that is not only integer corners (one naming a uv or
# a normal, or a malformed one, which is left to trimesh and its messages as it is).
_NOT_PLAIN = re.compile(r"^(?:vt|vn)[ \t]|^f[ \t](?![ \t]*-?\d+(?:[ \t]+-?\d+)*[ \t]*$)", re.MULTILINE)
_FACE = re.compile(r"^(f[ \t])([^\n]*)$", re.MULTILINE)


def paired_indices(text: str) -> str:
    """``text`` (statements as :func:`farfield.core.exchange.obj.plain_statements` leaves them) with
    each face corner ``i`` written ``i/i`` where the file has no ``vt``, no ``vn`` and only faces of
    integer corners; otherwise ``text`` itself.

    >>> paired_indices("v 0 0 0\\nv 1 0 0\\nv 0 1 0\\no a\\nf 1 2 3\\n")
    'v 0 0 0\\nv 1 0 0\\nv 0 1 0\\no a\\nf 1/1 2/2 3/3\\n'
    >>> paired_indices("vt 0 0\\nf 1/1 2/1 3/1\\n"), paired_indices("f 1 2 3\\nf 1 2.5 3\\n")
    ('vt 0 0\\nf 1/1 2/1 3/1\\n', 'f 1 2 3\\nf 1 2.5 3\\n')
    """
    if _NOT_PLAIN.search(text) is not None:
        return text
    return _FACE.sub(lambda face: face[1] + " ".join([c + "/" + c for c in face[2].split()]), text)
