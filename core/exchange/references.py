"""File references of a scene (an MTL map line, a glTF ``uri``) -> the one file (a relative POSIX name) they
name, by one rule for a folder on disk and for the files of an upload.

A reference is looked up as written, then as a path (URL-decoded, ``\\`` as ``/``, ``./`` dropped),
then by its base name, then as the file of an MTL map statement (its options skipped), then by its last word, each
candidate exactly, then ignoring case, then by its base name where one file has that base name:
references come from other systems (a Windows exporter writes ``Textures\\Leaf.PNG`` for
``textures/leaf.png``).  The same scene therefore loads the same textures, and has the same
content hash, from its folder and from an upload of that folder.

MTL map statements (``map_Kd -s 2 2 1 -imfchan r leaf.png``) are split by :func:`map_statement`
into their options and file name, after the MTL specification's option list (Wavefront's "MTL
material format", Lightwave's reprint, "Options for texture map statements").
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from dataclasses import dataclass, field
from urllib.parse import unquote

# Options of a texture map statement and how many arguments each takes at most; -o, -s, -t take
# one to three numbers and -mm one or two (u, then optional v and w; base, then optional gain).
MAP_OPTIONS = {
    "-blendu": 1, "-blendv": 1, "-bm": 1, "-boost": 1, "-cc": 1, "-clamp": 1, "-imfchan": 1,
    "-mm": 2, "-o": 3, "-s": 3, "-t": 3, "-texres": 1, "-type": 1,
}  # fmt: skip
_NUMERIC_OPTIONS = ("-o", "-s", "-t", "-mm")

# A folder scan for references that are not found as written stops after this many files (a scene
# kept in a home folder must not walk the whole disk); what it did not reach is not found.
MAX_FOLDER_FILES = 20_000


def _is_number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


@dataclass(frozen=True, slots=True)
class MapStatement:
    """A texture map statement's file name and options (``{"s": ("2", "2", "1"), "imfchan": ("r",)}``)."""

    file: str
    options: dict[str, tuple[str, ...]] = field(default_factory=dict)


def map_statement(rest: str) -> MapStatement:
    """Split what follows a map keyword into its options and file name.

    >>> map_statement("-s 2 2 1 -imfchan r my leaf.png")
    MapStatement(file='my leaf.png', options={'s': ('2', '2', '1'), 'imfchan': ('r',)})
    >>> map_statement("-o 0.5 leaf.png").options, map_statement("leaf.png").file
    ({'o': ('0.5',)}, 'leaf.png')
    """
    tokens = rest.split()
    options: dict[str, tuple[str, ...]] = {}
    i = 0
    while i < len(tokens) - 1 and tokens[i].lower() in MAP_OPTIONS:
        key = tokens[i].lower()
        i += 1
        args: list[str] = []
        while (
            len(args) < MAP_OPTIONS[key]
            and i < len(tokens) - 1
            and (key not in _NUMERIC_OPTIONS or _is_number(tokens[i]))
        ):
            args.append(tokens[i])
            i += 1
            if key not in _NUMERIC_OPTIONS:
                break
        options[key[1:]] = tuple(args)
    return MapStatement(" ".join(tokens[i:]) if tokens else rest.strip(), options)


def _path(text: str) -> str:
    """``text`` as a relative POSIX path: URL-decoded, ``\\`` as ``/``, empty and ``.`` parts dropped."""
    text = unquote(text).replace("\\", "/")
    return "/".join(p for p in text.split("/") if p not in ("", "."))


def candidates(reference: str) -> list[str]:
    """The names a reference may mean, most literal first (see the module docstring)."""
    path = _path(reference)
    out = [reference, path, path.rsplit("/", 1)[-1], _path(map_statement(reference).file)]
    words = reference.split()
    if words:
        out.append(_path(words[-1]))
    return list(dict.fromkeys(c for c in out if c))


class FileIndex:
    """The files a reference may name (relative POSIX names), and the lookup of a reference among them."""

    def __init__(self, names: Iterable[str]):
        self.names = set(names)
        self._folded: dict[str, str] = {}
        bases: dict[str, list[str]] = {}
        for name in sorted(self.names):
            self._folded.setdefault(name.lower(), name)
            bases.setdefault(name.rsplit("/", 1)[-1].lower(), []).append(name)
        self._bases = {base: found[0] for base, found in bases.items() if len(found) == 1}  # unique base names only

    @classmethod
    def of_folder(cls, directory: str | os.PathLike) -> FileIndex:
        """The files under ``directory`` (hidden folders skipped; at most :data:`MAX_FOLDER_FILES`)."""
        names: list[str] = []
        for top, folders, files in os.walk(directory):
            folders[:] = sorted(f for f in folders if not f.startswith("."))
            relative = os.path.relpath(top, directory).replace(os.sep, "/")
            for name in sorted(files):
                names.append(name if relative == "." else f"{relative}/{name}")
                if len(names) >= MAX_FOLDER_FILES:
                    return cls(names)
        return cls(names)

    def find(self, reference: str) -> str | None:
        """The name ``reference`` means, or None."""
        for candidate in candidates(reference):
            base = candidate.rsplit("/", 1)[-1].lower()
            for key in (candidate, self._folded.get(candidate.lower()), self._bases.get(base)):
                if key is not None and key in self.names:
                    return key
        return None
