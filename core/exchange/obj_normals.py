"""OBJ ``vn`` references per face corner, checked and completed before trimesh parses the text.

A face corner ``v/vt/vn`` or ``v//vn`` names its shading normal (Wavefront OBJ specification,
"Referencing groups of vertices"); a position used with different normals (or uv) at different
corners becomes separate vertices, which trimesh's ``unmerge_faces`` does, as it does for uv.  What
trimesh 4.12 gets wrong, and this module corrects in the text it is given:

* a ``vn`` index beyond the ``vn`` lines is dropped in silence, and with it every normal of the
  object: here it is a :class:`SceneLoadError` naming the line;
* one face without normal indices among faces with them (``f 1 2 3`` beside ``f 4//1 5//1 6//1``)
  makes it drop every normal of the object: here each corner without one is given its face's normal
  (the polygon's area vector, ``sum (p_i - p_0) x (p_{i+1} - p_0)``, the front of its
  counter-clockwise order), appended as a new ``vn`` line, so the face is drawn flat as it would be
  without normals while the others keep theirs.  This is done for every face of a file in which any
  face names a normal (trimesh groups a file's faces by object and material across the file).

A file without ``vn`` references is returned unchanged, so its objects and their hashes are as
before.  Negative indices are resolved as trimesh resolves them (from the end of the file's list):
:mod:`farfield.core.exchange.obj_indices` has made absolute those that would be misread so.
"""

from __future__ import annotations

import re

import numpy as np

from farfield.core.errors import SceneLoadError

_VN = re.compile(r"^[ \t]*vn[ \t]", re.MULTILINE)
_V = re.compile(r"^[ \t]*v[ \t]+([^\r\n]*)", re.MULTILINE)
_FACE = re.compile(r"^([ \t]*f[ \t]+)([^\r\n]*)", re.MULTILINE)
_FULL_CORNER = re.compile(r"(?<!\S)[^\s/]+/[^\s/]*/(-?\d+)(?!\S)")


def _line(text: str, at: int) -> int:
    """1-based line number of the character ``at``."""
    return text.count("\n", 0, at) + 1


def _resolve(index: int, count: int) -> int:
    """0-based index of an OBJ index (1-based, negative from the end, as trimesh takes it), or -1."""
    resolved = index - 1 if index > 0 else count + index
    return resolved if 0 <= resolved < count else -1


def _positions(text: str) -> np.ndarray:
    """(v, 3) float64 positions of the ``v`` lines (vertex colours after them ignored)."""
    try:
        return np.array([line.split()[:3] for line in _V.findall(text)], dtype=np.float64).reshape(-1, 3)
    except ValueError as error:
        raise SceneLoadError(f"a 'v' line is not three numbers: {error}") from error


def _bad_normal(text: str, match: re.Match, corner: str, count: int) -> SceneLoadError:
    return SceneLoadError(
        f"line {_line(text, match.start())}: face corner {corner!r} names normal (vn) "
        f"{corner.rsplit('/', 1)[1]}, but the file has {count} vn lines"
    )


def complete_normals(text: str) -> str:
    """``text`` with every face corner naming a normal that exists (see the module docstring).

    Raises
    ------
    SceneLoadError
        A corner names a ``vn`` beyond the file's ``vn`` lines (or a ``v`` beyond its ``v`` lines,
        on a face that needs its face normal).

    Examples
    --------
    >>> complete_normals("v 0 0 0\\nv 1 0 0\\nv 0 1 0\\nvn 0 0 1\\nf 1//1 2//1 3//1\\nf 1 2 3\\n").splitlines()[-2:]
    ['f 1//2 2//2 3//2', 'vn 0.0 0.0 1.0']
    """
    count = len(_VN.findall(text))
    faces = _FACE.findall(text)
    if not faces:
        return text
    corners = " ".join(body.split("#", 1)[0] for _, body in faces).split()
    named = _FULL_CORNER.findall(" ".join(corners))
    if not named:
        return text  # no face names a normal: trimesh reads the file as before
    try:
        indices = np.array(named, dtype=np.int64)
    except (OverflowError, ValueError):  # an index of 20 digits: the loop below names it
        indices = np.array([-1 - count], dtype=np.int64)
    resolved = np.where(indices > 0, indices - 1, count + indices)
    if len(named) == len(corners) and resolved.min() >= 0 and resolved.max() < count:
        return text  # every corner names a normal that exists
    positions = None
    added: list[np.ndarray] = []

    def face(match: re.Match) -> str:
        nonlocal positions
        parts = [corner.split("/") for corner in match.group(2).split("#", 1)[0].split()]
        out, missing = [], []
        relative = False
        for corner in parts:
            if len(corner) >= 3 and corner[2]:
                try:
                    at = _resolve(int(corner[2]), count)
                except ValueError:
                    at = -1
                if at < 0:
                    raise _bad_normal(text, match, "/".join(corner), count)
                # Normals appended below would move what a negative index (counted from the end)
                # names: every one is written absolute.
                relative = relative or int(corner[2]) < 0
                out.append("/".join([*corner[:2], str(at + 1), *corner[3:]]))
            else:
                missing.append(len(out))
                out.append(None)
        if not missing or len(parts) < 3:
            return match.group(1) + " ".join(out) if relative and not missing else match.group(0)
        if positions is None:
            positions = _positions(text)
        try:
            at = [_resolve(int(corner[0]), len(positions)) for corner in parts]
        except ValueError as error:
            raise SceneLoadError(f"line {_line(text, match.start())}: {match.group(0).strip()!r}: {error}") from None
        if min(at) < 0:
            raise SceneLoadError(
                f"line {_line(text, match.start())}: {match.group(0).strip()!r} names a vertex beyond the "
                f"file's {len(positions)} v lines"
            )
        p = positions[at]
        area = np.cross(p[1:-1] - p[0], p[2:] - p[0]).sum(axis=0)  # the polygon's area vector (its fan's)
        added.append(area)
        index = count + len(added)
        for k in missing:
            corner = parts[k]
            out[k] = f"{corner[0]}/{corner[1] if len(corner) > 1 else ''}/{index}"
        return match.group(1) + " ".join(out)

    text = _FACE.sub(face, text)
    if not added:
        return text
    lines = "\n".join(f"vn {x!r} {y!r} {z!r}" for x, y, z in np.array(added).tolist())
    return text + ("" if text.endswith("\n") else "\n") + lines + "\n"
