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

A file that mixes objects with ``vt`` and objects without (``f 1/1 2/2 3/3`` in one, ``f 4 5 6`` in
another) kept the masks for the latter: ``i/i`` there would name uvs that exist.  Their corners are
written ``i/K`` instead, ``K`` one past the file's last ``vt``: trimesh takes the same linear
branch, its ``vt[mask_vt]`` fails on ``K`` as on a file without ``vt``, and such an object keeps no
uv, as the OBJ format has it (a face without ``vt`` has no texture coordinates, so its material's
texture is not sampled) and as trimesh's masks gave.  Only where every piece trimesh makes (an
``o`` object and ``usemtl`` material) is all with ``vt`` or all without: trimesh reads a piece
mixing both as one without uvs, and ``i/K`` would split its vertices there.
"""

from __future__ import annotations

import re

import numpy as np

# A vt or vn statement anywhere, or a face line that is not only integer corners (one naming a uv or
# a normal, or a malformed one, which is left to trimesh and its messages as it is).
# A line may end in CR LF (plain_statements keeps the CR; trimesh reads it so).
_NOT_PLAIN = re.compile(r"^(?:vt|vn)[ \t]|^f[ \t](?![ \t]*-?\d+(?:[ \t]+-?\d+)*[ \t]*\r?$)", re.MULTILINE)
_FACE = re.compile(r"^(f[ \t])([^\r\n]*)", re.MULTILINE)

# Pair where pieces x vertices > PAIR_ABOVE x faces: objects of n triangles on a shared file's
# vertices load equally fast both ways near pieces x vertices / faces = 700 (bench_loading.py
# --pieces, docs/measurements/loading.md); the masks are the faster below, the pairing above.
PAIR_ABOVE = 700


# In a file with vt, a face line without "/" (its corners are to be written i/K; checked by _CORNERS),
# and one with (left as it is).  Both start after a newline (_past_the_uvs pads the text with one).
_PLAIN_LINE = re.compile(r"\nf[ \t]([^/\n]*)(?=\n)")
_SLASH_LINE = re.compile(r"\nf[ \t][^\n]*/")
_WORD = re.compile(r"\S")
# A negative index (trimesh reads one after the file's last v as written) leaves the file as written.
_CORNERS = re.compile(r"[ \t]*\d+(?:[ \t]+\d+){2,}[ \t]*\r?")


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
    if not pays(text):
        return text
    if _NOT_PLAIN.search(text) is None:
        return _FACE.sub(lambda face: face[1] + " ".join([c + "/" + c for c in face[2].split()]), text)
    return _past_the_uvs(text)


def _pieces(text: str) -> tuple[np.ndarray, np.ndarray]:
    """Where trimesh's reader starts a piece in ``text`` (``usemtl `` anywhere, ``\\no ``: its
    ``_preprocess_faces``), ascending, and each piece's key, the ``(usemtl, o)`` pair it tracks from
    piece to piece, as an integer (pieces before the first start have key 0).  Names as trimesh
    reads them: ``o a usemtl red`` names ``a``, and an ``o`` with nothing before the next start
    (``o usemtl red``) none (the last name stays); two nameless ``o`` are one object."""
    starts = []
    for marker in ("usemtl ", "\no "):
        at = text.find(marker)
        while at >= 0:
            starts.append(at)
            at = text.find(marker, at + 1)
    starts.sort()
    keys: dict[tuple[str | None, str | None], int] = {(None, None): 0}
    ids = np.empty(len(starts), dtype=np.int64)
    material = name = None
    for k, at in enumerate(starts):
        # a piece's first line, as trimesh reads it: up to the next start (the docstring)
        after = starts[k + 1] if k + 1 < len(starts) else len(text)
        end = min(text.find("\n", at + 1), after)
        line = text[at:end].strip()
        if line.startswith("usemtl"):
            material = line[6:].strip()
        elif line != "o" or _WORD.search(text, end, after) is not None:
            name = line[2:].strip()
        ids[k] = keys.setdefault((material, name), len(keys))
    return np.asarray(starts, dtype=np.int64), ids


def _past_the_uvs(text: str) -> str:
    """``text`` with each corner ``i`` of a face without ``vt`` written ``i/K`` (``K`` past the file's
    last line, so past its last ``vt``) where the file has ``vt`` and each of trimesh's pieces is all
    faces with ``/`` or all without (the module docstring); otherwise ``text`` itself.

    >>> text = "v 0 0 0\\nv 1 0 0\\nv 0 1 0\\nvt 0 0\\no a\\nf 1/1 2/1 3/1\\no b\\nf 1 2 3\\n"
    >>> _past_the_uvs(text)[-21:]
    'o b\\nf 1/11 2/11 3/11\\n'
    >>> _past_the_uvs(text.replace("o b\\n", "")) == text.replace("o b\\n", "")  # one piece, both kinds
    True
    """
    if not _statements(text, "vt"):
        return text
    padded = "\n" + text + "\n"
    plain = [m.start() for m in _PLAIN_LINE.finditer(padded)]
    if not plain:
        return text
    starts, keys = _pieces(padded)
    with_uv = [m.start() for m in _SLASH_LINE.finditer(padded)]
    pieces = [np.concatenate([[0], keys])[np.searchsorted(starts, at, side="right")] for at in (plain, with_uv)]
    if np.intersect1d(*pieces).size:
        return text  # a piece of both kinds: trimesh reads it as one without uvs, one vertex per v
    past = f"/{padded.count(chr(10)) + 1}"
    bad = []

    def corners(face: re.Match) -> str:
        body = face[1]
        if _CORNERS.fullmatch(body) is None:
            bad.append(face)
            return face[0]
        end = "\r" if body.endswith("\r") else ""
        return face[0][:3] + (past + " ").join(body.split()) + past + end

    paired = _PLAIN_LINE.sub(corners, padded)
    return text if bad else paired[1:-1]
