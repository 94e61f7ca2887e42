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

The pairing is not free: the face text grows, and ``unmerge_faces`` sorts each piece's corners, about
1.9 us a face more, where the masks cost about 3 ns a piece and vertex.  A file of one large object
(a scan, a terrain: 2,000,000 triangles) loaded 1.6x slower and with 27% more peak memory paired,
so only a file whose pieces x vertices exceed :data:`PAIR_ABOVE` x faces is paired (the crossover
measured in docs/measurements/loading.md); below it trimesh's masks cost at most about as much as
the pairing would, so no file is quadratic either way.
"""

from __future__ import annotations

import re

# A vt or vn statement anywhere, or a face line that is not only integer corners (one naming a uv or
# a normal, or a malformed one, which is left to trimesh and its messages as it is).
# A line may end in CR LF (plain_statements keeps the CR; trimesh reads it so).
_NOT_PLAIN = re.compile(r"^(?:vt|vn)[ \t]|^f[ \t](?![ \t]*-?\d+(?:[ \t]+-?\d+)*[ \t]*\r?$)", re.MULTILINE)
_FACE = re.compile(r"^(f[ \t])([^\r\n]*)", re.MULTILINE)

# Pair where pieces x vertices > PAIR_ABOVE x faces: objects of n triangles on a shared file's
# vertices load equally fast both ways near pieces x vertices / faces = 700 (bench_loading.py
# --pieces, docs/measurements/loading.md); the masks are the faster below, the pairing above.
PAIR_ABOVE = 700


def _statements(text: str, keyword: str) -> int:
    """How many lines of ``text`` begin with ``keyword`` and a space (at memchr speed, no regex)."""
    return text.count("\n" + keyword + " ") + text.startswith(keyword + " ")


def pays(text: str) -> bool:
    """Whether trimesh's masks (pieces x vertices) would cost more than the pairing (faces): a
    piece is an ``o`` object or a ``usemtl`` run (an over-count where materials repeat)."""
    pieces = max(1, _statements(text, "o") + _statements(text, "usemtl"))
    return pieces * _statements(text, "v") > PAIR_ABOVE * _statements(text, "f")


def paired_indices(text: str) -> str:
    """``text`` (statements as :func:`farfield.core.exchange.obj.plain_statements` leaves them) with
    each face corner ``i`` written ``i/i`` where the file has no ``vt``, no ``vn`` and only faces of
    integer corners, and the pairing :func:`pays`; otherwise ``text`` itself.

    >>> paired_indices("v 0 0 0\\nv 1 0 0\\nv 0 1 0\\no a\\nf 1 2 3\\n")  # a file of one object: as it is
    'v 0 0 0\\nv 1 0 0\\nv 0 1 0\\no a\\nf 1 2 3\\n'
    >>> paired_indices("v 0 0 0\\n" * 701 + "o a\\nf 1 2 3\\n")[-18:]  # 1 x 701 vertices > 700 x 1 face
    'o a\\nf 1/1 2/2 3/3\\n'
    >>> paired_indices("v 0 0 0\\r\\n" * 701 + "f 1 2 3\\r\\n")[-15:]  # CR LF lines
    'f 1/1 2/2 3/3\\r\\n'
    >>> paired_indices("vt 0 0\\nf 1/1 2/1 3/1\\n"), paired_indices("f 1 2 3\\nf 1 2.5 3\\n")
    ('vt 0 0\\nf 1/1 2/1 3/1\\n', 'f 1 2 3\\nf 1 2.5 3\\n')
    """
    if not pays(text) or _NOT_PLAIN.search(text) is not None:
        return text
    return _FACE.sub(lambda face: face[1] + " ".join([c + "/" + c for c in face[2].split()]), text)
