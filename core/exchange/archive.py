"""Multi-file scenes: a zip of one scene file and the files it refers to (an OBJ's MTL and textures, a
glTF's buffers and images), read with bounds; and such a zip packed from a scene file on disk.

**Reading** (:func:`read_scene_archive`, an upload): the archive must hold exactly one scene file
(``.glb``, ``.gltf``, ``.obj``, ``.ply``, ``.stl``; anywhere in it); every other file inside the
scene file's folder is an asset, keyed by its path relative to that folder, which is how the scene
names it.  Nothing is written to disk and references resolve only among those assets, so a name
cannot reach outside the upload; still, a member named with ``..``, an absolute path or a drive is
refused, as are more than ``MAX_FILES`` files, more than ``limit`` bytes uncompressed (counted as
they are read, not as the archive declares) and a member that inflates more than ``MAX_RATIO``
times (a zip bomb).  macOS's ``__MACOSX/`` and ``._*`` entries are skipped.

**Packing** (:func:`pack_scene`, the client): a ``.gltf``'s buffer and image URIs and an ``.obj``'s
``mtllib`` files and their ``map_*`` textures, those that exist beside it and do not leave its
folder, zipped with the scene file at the top.
"""

from __future__ import annotations

import io
import json
import re
import zipfile
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath

from farfield.core.errors import SceneLoadError, UploadTooLargeError

SCENE_EXTENSIONS = ("glb", "gltf", "obj", "ply", "stl")
MAX_FILES = 2000  # members of an uploaded archive
MAX_RATIO = 200  # uncompressed / compressed of one member, past MIN_RATIO_BYTES
MIN_RATIO_BYTES = 1 << 20  # small members may compress as well as they like
_DRIVE = re.compile(r"^[A-Za-z]:")


@dataclass(frozen=True)
class SceneArchive:
    """An archive's scene file (its name and bytes) and its assets by the name the scene uses."""

    name: str
    data: bytes
    assets: dict[str, bytes] = field(default_factory=dict)
    skipped: tuple[str, ...] = ()  # members outside the scene file's folder (no reference can reach them)


def is_zip(data_or_path) -> bool:
    """Whether bytes or a file start like a zip archive."""
    if isinstance(data_or_path, (bytes, bytearray)):
        return bytes(data_or_path[:4]) == b"PK\x03\x04"
    with open(data_or_path, "rb") as f:
        return f.read(4) == b"PK\x03\x04"


def member_path(name: str) -> PurePosixPath:
    """An archive member's path, checked: relative, no ``..``, no drive (SceneLoadError otherwise).

    >>> str(member_path("./models/duck.obj"))
    'models/duck.obj'
    """
    text = name.replace("\\", "/")
    path = PurePosixPath(text)
    if text.startswith("/") or _DRIVE.match(text) or ".." in path.parts:
        raise SceneLoadError(f"archive member {name!r}: a path outside the archive (absolute, a drive or '..') is refused")
    return PurePosixPath(*[p for p in path.parts if p not in ("", ".")])


def read_scene_archive(source, limit: int, archive_name: str = "upload.zip") -> SceneArchive:
    """The scene and assets of a zip (bytes, a path or a binary file), checked as the module says."""
    try:
        archive = zipfile.ZipFile(io.BytesIO(source) if isinstance(source, (bytes, bytearray)) else source)
    except (zipfile.BadZipFile, OSError) as error:
        raise SceneLoadError(f"{archive_name}: not a readable zip archive ({error})") from None
    with archive:
        infos = [i for i in archive.infolist() if not i.is_dir() and not i.filename.startswith("__MACOSX/") and not PurePosixPath(i.filename).name.startswith("._")]
        if len(infos) > MAX_FILES:
            raise UploadTooLargeError(f"{archive_name}: {len(infos)} files, more than the {MAX_FILES} an archive may hold")
        paths = [member_path(i.filename) for i in infos]
        scenes = [p for p in paths if p.suffix.lower().lstrip(".") in SCENE_EXTENSIONS]
        if len(scenes) != 1:
            found = ", ".join(str(p) for p in scenes[:10]) or "none"
            raise SceneLoadError(
                f"{archive_name}: an archive holds exactly one scene file ({', '.join('.' + e for e in SCENE_EXTENSIONS)}) and the files it refers to; found {found}"
            )
        scene = scenes[0]
        total, data, assets, skipped = 0, b"", {}, []
        for info, path in zip(infos, paths, strict=True):
            if info.file_size > MIN_RATIO_BYTES and info.file_size > MAX_RATIO * max(info.compress_size, 1):
                raise UploadTooLargeError(f"{archive_name}: member {path} inflates {info.file_size / max(info.compress_size, 1):.0f} times (a zip bomb?); at most {MAX_RATIO}")
            inside = path.parent == scene.parent or scene.parent in path.parents
            if not inside:
                skipped.append(str(path))
                continue
            with archive.open(info) as member:
                body = member.read(limit - total + 1)
            total += len(body)
            if total > limit:
                raise UploadTooLargeError(f"{archive_name}: more than {limit // 2**20} MiB uncompressed, the upload limit")
            if path == scene:
                data = body
            else:
                assets[str(path.relative_to(scene.parent))] = body
        return SceneArchive(scene.name, data, assets, tuple(skipped))


def assets_zip(assets: dict[str, bytes]) -> bytes:
    """Assets as a zip of their names (what the service stores beside a scene)."""
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", zipfile.ZIP_STORED) as archive:
        for name, body in sorted(assets.items()):
            archive.writestr(name, body)
    return out.getvalue()


def read_assets_zip(data: bytes) -> dict[str, bytes]:
    """The assets of :func:`assets_zip`."""
    with zipfile.ZipFile(io.BytesIO(data)) as archive:
        return {name: archive.read(name) for name in archive.namelist()}


_URI_SCHEME = re.compile(r"^[A-Za-z][A-Za-z0-9+.-]*:")


def _local(reference: str) -> str | None:
    """A reference that names a file beside the scene (not a data, file: or http URI; not ``..``)."""
    from urllib.parse import unquote

    reference = reference.strip().replace("\\", "/")
    if not reference or _URI_SCHEME.match(reference) or reference.startswith("/"):
        return None
    path = PurePosixPath(unquote(reference))
    if ".." in path.parts:
        return None
    return str(PurePosixPath(*[p for p in path.parts if p not in ("", ".")]))


def referenced_files(path: Path) -> list[str]:
    """The files a ``.gltf`` or ``.obj`` at ``path`` refers to that exist beside it (relative names)."""
    path = Path(path)
    suffix = path.suffix.lower()
    found: list[str] = []
    if suffix == ".gltf":
        try:
            document = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError, UnicodeDecodeError):
            return []
        uris = [b.get("uri") for b in document.get("buffers", []) if isinstance(b, dict)] + [i.get("uri") for i in document.get("images", []) if isinstance(i, dict)]
        found = [r for r in (_local(u) for u in uris if isinstance(u, str)) if r]
    elif suffix == ".obj":
        libraries = []
        for line in path.read_text(encoding="utf-8", errors="replace").splitlines():
            if line.startswith("mtllib"):
                libraries += [r for r in (_local(t) for t in line.split()[1:]) if r]
        found = list(libraries)
        for library in libraries:
            mtl = path.parent / library
            if not mtl.is_file():
                continue
            for line in mtl.read_text(encoding="utf-8", errors="replace").splitlines():
                words = line.split()
                if words and words[0].lower().startswith(("map_", "bump", "disp", "decal", "refl", "norm")) and len(words) > 1:
                    local = _local(words[-1])  # options (-s 1 1 1, ...) come first; the file name is last
                    if local:
                        found.append(str((PurePosixPath(library).parent / local)) if PurePosixPath(library).parent != PurePosixPath(".") else local)
    seen, out = set(), []
    for name in found:
        if name not in seen and (path.parent / name).is_file():
            seen.add(name)
            out.append(name)
    return out


def pack_scene(path: Path) -> bytes | None:
    """A zip of the scene file at ``path`` and the files it refers to, or None when it refers to none."""
    path = Path(path)
    references = referenced_files(path)
    if not references:
        return None
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as archive:
        archive.write(path, path.name)
        for name in references:
            archive.write(path.parent / name, name)
    return out.getvalue()
