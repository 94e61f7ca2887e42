"""OBJ face indices: relative (negative) ones made absolute, counted where the face stands, before trimesh parses the text; one beyond its list named.

The Wavefront OBJ specification ("Referencing vertex data"): "If an index is negative then it
relatively refers to the end of the vertex list, -1 referring to the last element", the list as
read so far: ``f -3 -2 -1`` after three ``v`` lines names those three, whatever follows.  Exporters
that write each object on its own use it so, and three.js's OBJLoader reads it so (the index plus
the vertices parsed before the face).  trimesh 4.12 counts from the end of the whole file, so every
such object but the last drew the last one's vertices: a file of objects written one after the
other drew a single object, several times.  Here each relative index of a face (``f``) or line
(``l``), for positions, texture coordinates and normals alike, is written as the absolute index it
names; one that reaches before the first element is refused, naming its line.

A file is returned unchanged where trimesh reads it right: without relative indices, or with
every one after its last ``v``, ``vt`` and ``vn`` lines (vertices first, then faces), where
counting back from the end of the file is counting back from the face.  Scans at memory speed for
``f -``, ``l -``, ``/-`` and the last element lines find them, so a face whose first corner is
absolute and a later one relative without slashes (``f 1 -2 -1``), in a file with no other, is
read as trimesh reads it; and relative indices are checked for range only where they are
rewritten (trimesh takes one before the first element from the end of the list).
"""

from __future__ import annotations

import re

from farfield.core.errors import SceneLoadError

_KINDS = ("v", "vt", "vn")  # the elements of a corner's slots v/vt/vn
_NAMES = ("vertex (v)", "texture coordinate (vt)", "normal (vn)")
_ELEMENTS = ("\nv ", "\nvt ", "\nvn ")


def _misread(text: str) -> bool:
    """Whether trimesh may misread a relative index of ``text``: one may be there, and a ``v``,
    ``vt`` or ``vn`` line follows it (scans at memory speed, module docstring)."""
    found = [at for at in (text.find(mark) for mark in ("/-", "\nf -", "\nl -")) if at >= 0]
    if text.startswith(("f -", "l -")):
        found.append(0)
    return bool(found) and max(text.rfind(mark) for mark in _ELEMENTS) > min(found)


# A face or line statement with a minus sign in it (its line, without the newline).
_SIGNED = re.compile(r"^[fl] [^\n]*-[^\n]*", re.MULTILINE)


def absolute_indices(text: str) -> str:
    """``text`` with every relative index of its faces and lines written absolute (module docstring).

    Raises
    ------
    SceneLoadError
        A relative index names an element before the first (``f -4`` after three ``v`` lines).

    Examples
    --------
    >>> absolute_indices("v 0 0 0\\nv 1 0 0\\nv 0 1 0\\nf -3 -2 -1\\nv 5 0 0\\nf -3 -2 -1\\n").splitlines()[-3::2]
    ['f 1 2 3', 'f 2 3 4']
    >>> absolute_indices("vt 0 0\\nvn 0 0 1\\nv 0 0 0\\nv 1 0 0\\nv 0 1 0\\nf -3/-1/-1 -2/-1/-1 -1/-1/-1\\nvn 1 0 0\\n").splitlines()[-2]
    'f 1/1/1 2/1/1 3/1/1'
    >>> absolute_indices("v 0 0 0\\nv 1 0 0\\nv 0 1 0\\nf -3 -2 -1\\n")  # vertices first: as it is
    'v 0 0 0\\nv 1 0 0\\nv 0 1 0\\nf -3 -2 -1\\n'
    """
    if not _misread(text):
        return text
    text = "\n" + text  # every statement's line follows a newline
    counts = [0, 0, 0]
    done = 0  # the elements before here are counted

    def face(match: re.Match) -> str:
        nonlocal done
        for k, mark in enumerate(_ELEMENTS):
            counts[k] += text.count(mark, done, match.start())
        done = match.end()
        try:
            return _face(match.group(0), counts)
        except SceneLoadError as error:
            raise SceneLoadError(f"line {text.count(chr(10), 0, match.start())}: {error}") from None

    return _SIGNED.sub(face, text)[1:]


def _face(line: str, counts: list[int]) -> str:
    """A face or line statement with its relative indices made absolute against ``counts``."""
    words = line.rstrip("\r").split(" ")
    for w, word in enumerate(words[1:], start=1):
        if "-" not in word:
            continue
        slots = word.split("/")
        for k, slot in enumerate(slots[:3]):
            if not slot.startswith("-"):
                continue
            try:
                index = int(slot)
            except ValueError:
                continue  # not a number: trimesh's parse refuses the file
            absolute = counts[k] + index + 1
            if absolute < 1:
                raise SceneLoadError(
                    f"{line.strip()[:60]!r} names {_NAMES[k]} {index}, but only "
                    f"{counts[k]} {_KINDS[k]} lines come before it"
                )
            slots[k] = str(absolute)
        words[w] = "/".join(slots)
    return " ".join(words) + ("\r" if line.endswith("\r") else "")


_FACE_LINE = re.compile(r"^[fl] ([^\n]*)", re.MULTILINE)


def beyond_the_end(text: str) -> SceneLoadError | None:
    """The error naming the first face or line of ``text`` (relative indices already absolute) whose
    vertex or texture coordinate index is beyond the file's ``v`` or ``vt`` lines, or None.  Only
    run where trimesh's parse failed (its IndexError names no line); normals are checked by
    :mod:`farfield.core.exchange.obj_normals`.

    >>> str(beyond_the_end("v 0 0 0\\nv 1 0 0\\nv 0 1 0\\nf 1 2 3\\nf 1 2 4\\n"))
    "line 5: 'f 1 2 4' names vertex (v) 4, but the file has 3 v lines"
    """
    counts = [("\n" + text).count(mark) for mark in _ELEMENTS[:2]]
    for match in _FACE_LINE.finditer(text):
        for corner in match.group(1).split():
            for k, slot in enumerate(corner.split("/")[:2]):
                try:
                    index = int(slot)
                except ValueError:
                    continue
                if index > counts[k] or -index > counts[k]:  # a relative one left here counts from the end
                    line = text.count("\n", 0, match.start()) + 1
                    return SceneLoadError(
                        f"line {line}: {match.group(0).strip()[:60]!r} names {_NAMES[k]} {index}, but the file has "
                        f"{counts[k]} {_KINDS[k]} lines"
                    )
    return None
