"""Multi-file scenes: a zip of one scene file and the files it refers to (an OBJ's MTL and textures, a
glTF's buffers and images), read with bounds; and such a zip packed from a scene file on disk.

**Reading** (:func:`unpack_scene_archive`, an upload; :func:`parts_archive` for several files
uploaded at once): the archive must hold exactly one scene file
(``.glb``, ``.gltf``, ``.obj``, ``.ply``, ``.stl``; anywhere in it); every other file inside the
scene file's folder is an asset, keyed by its path relative to that folder, which is how the scene
names it.  Members are copied in chunks into the caller's temporary folder (the scene file, and the
assets as one stored zip), never whole into memory, and references resolve only among those assets,
so a name cannot reach outside the upload; still, a member named with ``..``, an absolute path or a
drive is refused, as are two names that differ only in case, an encrypted or corrupt member, more
than ``MAX_FILES`` files (counted from the end record before zipfile reads the directory), more than
``limit`` bytes uncompressed (counted as they are read, not as the archive declares) and a member
that inflates more than ``MAX_RATIO`` times (a zip bomb).  macOS's ``__MACOSX/`` and ``._*``
entries are skipped.

**Packing** (:func:`pack_scene`, the client): a ``.gltf``'s buffer and image URIs and an ``.obj``'s
``mtllib`` files and their ``map_*`` textures, those that exist beside it and do not leave its
folder, zipped with the scene file at the top.
"""

from __future__ import annotations

import io
import json
import re
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

from farfield.core.errors import SceneLoadError, UploadTooLargeError
from farfield.core.exchange.gltf.document import uri_path
from farfield.core.exchange.references import FileIndex

SCENE_EXTENSIONS = ("glb", "gltf", "obj", "ply", "stl")
MAX_FILES = 2000  # members of an uploaded archive
MAX_RATIO = 200  # uncompressed / compressed of one member, past MIN_RATIO_BYTES
MIN_RATIO_BYTES = 1 << 20  # small members may compress as well as they like
_DRIVE = re.compile(r"^[A-Za-z]:")


@dataclass(frozen=True)
class SceneArchive:
    """An unpacked upload: the scene file's name and where its bytes are, and the zip of its assets
    (stored, members named as the scene names them), or None without assets."""

    name: str
    scene: Path
    assets: Path | None = None
    size: int = 0  # bytes unpacked, the scene's and the assets' together
    skipped: tuple[str, ...] = ()  # members outside the scene file's folder (no reference can reach them)


def is_zip(path) -> bool:
    """Whether a file starts like a zip archive."""
    with open(path, "rb") as f:
        return f.read(4) == b"PK\x03\x04"


def member_path(name: str) -> PurePosixPath:
    """An archive member's path, checked: relative, no ``..``, no drive (SceneLoadError otherwise).

    >>> str(member_path("./models/duck.obj"))
    'models/duck.obj'
    """
    text = name.replace("\\", "/")
    path = PurePosixPath(text)
    if text.startswith("/") or _DRIVE.match(text) or ".." in path.parts or "\x00" in text:
        raise SceneLoadError(
            f"archive member {name!r}: a path outside the archive (absolute, a drive or '..') is refused"
        )
    return PurePosixPath(*[p for p in path.parts if p not in ("", ".")])


def _entries(file, archive_name: str) -> None:
    """Refuse an archive whose central directory lists more than MAX_FILES entries, before zipfile
    reads it all into memory (millions of entries fit in an upload)."""
    try:
        end = zipfile._EndRecData(file)  # the end record (zip64's when there is one): entries, directory size
    except (OSError, ValueError):
        end = None
    if not end:
        raise SceneLoadError(f"{archive_name}: not a readable zip archive (no end of central directory)")
    entries, size = end[zipfile._ECD_ENTRIES_TOTAL], end[zipfile._ECD_SIZE]
    if entries > 2 * MAX_FILES or size > 2 * MAX_FILES * 1024:
        raise UploadTooLargeError(
            f"{archive_name}: {entries:,} entries, more than the {MAX_FILES} files an archive may hold"
        )
    file.seek(0)


_READ_ERRORS = (RuntimeError, NotImplementedError, zlib.error, zipfile.BadZipFile, EOFError, ValueError)


def _copy(source, target, budget: int, what: str, archive_name: str) -> int:
    """Copy ``source`` into ``target`` in chunks; at most ``budget`` bytes (UploadTooLargeError past it)."""
    copied = 0
    try:
        while chunk := source.read(1 << 20):
            copied += len(chunk)
            if copied > budget:
                raise UploadTooLargeError(f"{archive_name}: more than the upload limit uncompressed")
            target.write(chunk)
    except _READ_ERRORS as error:  # encrypted, an unknown method, corrupt data, a bad CRC
        raise SceneLoadError(
            f"{archive_name}: member {what} cannot be read ({type(error).__name__}: {error})"
        ) from None
    return copied


def unpack_scene_archive(path: Path, limit: int, work: Path, archive_name: str = "upload.zip") -> SceneArchive:
    """The scene and assets of the zip at ``path``, checked as the module says, written under the
    folder ``work`` (the scene file, and the assets as one zip): nothing is held in memory whole."""
    work = Path(work)
    with open(path, "rb") as file:
        _entries(file, archive_name)
        try:
            archive = zipfile.ZipFile(file)
        except (zipfile.BadZipFile, OSError, ValueError) as error:
            raise SceneLoadError(f"{archive_name}: not a readable zip archive ({error})") from None
        with archive:
            infos = [
                i
                for i in archive.infolist()
                if not i.is_dir()
                and not i.filename.startswith("__MACOSX/")
                and not PurePosixPath(i.filename).name.startswith("._")
            ]
            if len(infos) > MAX_FILES:
                raise UploadTooLargeError(
                    f"{archive_name}: {len(infos)} files, more than the {MAX_FILES} an archive may hold"
                )
            paths = [member_path(i.filename) for i in infos]
            scenes = [p for p in paths if p.suffix.lower().lstrip(".") in SCENE_EXTENSIONS]
            if len(scenes) != 1:
                found = ", ".join(str(p) for p in scenes[:10]) or "none"
                raise SceneLoadError(
                    f"{archive_name}: an archive holds exactly one scene file ({', '.join('.' + e for e in SCENE_EXTENSIONS)}) and the files it refers to; found {found}"
                )
            scene = scenes[0]
            total, skipped, names = 0, [], set()
            scene_file, assets_file = work / "scene", work / "assets.zip"
            with zipfile.ZipFile(assets_file, "w", zipfile.ZIP_STORED) as assets:
                for info, member in zip(infos, paths, strict=True):
                    if info.file_size > MIN_RATIO_BYTES and info.file_size > MAX_RATIO * max(info.compress_size, 1):
                        raise UploadTooLargeError(
                            f"{archive_name}: member {member} inflates {info.file_size / max(info.compress_size, 1):.0f} times (a zip bomb?); at most {MAX_RATIO}"
                        )
                    if not (member.parent == scene.parent or scene.parent in member.parents):
                        skipped.append(str(member))
                        continue
                    key = str(member.relative_to(scene.parent))
                    if key.lower() in names:
                        raise SceneLoadError(
                            f"{archive_name}: two members are named {key!r} (names differ only in case or in './'); send each file once"
                        )
                    names.add(key.lower())
                    try:
                        source = archive.open(info)
                    except _READ_ERRORS as error:
                        raise SceneLoadError(
                            f"{archive_name}: member {member} cannot be read ({type(error).__name__}: {error})"
                        ) from None
                    with source:
                        if member == scene:
                            with open(scene_file, "wb") as out:
                                total += _copy(source, out, limit - total, str(member), archive_name)
                        else:
                            with assets.open(key, "w") as out:
                                total += _copy(source, out, limit - total, str(member), archive_name)
            has_assets = len(names) > 1
            if not has_assets:
                assets_file.unlink()
            return SceneArchive(scene.name, scene_file, assets_file if has_assets else None, total, tuple(skipped))


def parts_archive(parts: list[tuple[str, Path]], work: Path) -> SceneArchive:
    """Several uploaded files (name as sent, spooled path) as one archive: one of them is the scene,
    the others are assets keyed by their names as sent (a browser sends base names)."""
    keyed: dict[str, Path] = {}
    for name, path in parts:
        key = PurePosixPath((name or "").replace("\\", "/")).name
        if not key or "\x00" in key:
            raise SceneLoadError(f"an uploaded file needs a name, got {name!r}")
        if key.lower() in {k.lower() for k in keyed}:
            raise SceneLoadError(f"two uploaded files are named {key!r}; send each file once")
        keyed[key] = Path(path)
    scenes = [k for k in keyed if PurePosixPath(k).suffix.lower().lstrip(".") in SCENE_EXTENSIONS]
    if len(scenes) != 1:
        raise SceneLoadError(
            f"several files upload one scene: exactly one scene file ({', '.join('.' + e for e in SCENE_EXTENSIONS)}) and the files it refers to; found {', '.join(scenes) or 'none'}"
        )
    scene = keyed.pop(scenes[0])
    assets_file = Path(work) / "assets.zip"
    with zipfile.ZipFile(assets_file, "w", zipfile.ZIP_STORED) as assets:
        for key, path in keyed.items():
            assets.write(path, key)
    size = scene.stat().st_size + sum(p.stat().st_size for p in keyed.values())
    return SceneArchive(scenes[0], scene, assets_file if keyed else None, size)


def read_assets_zip(data: bytes) -> dict[str, bytes]:
    """The assets of a stored assets zip, by name."""
    with zipfile.ZipFile(io.BytesIO(data)) as archive:
        return {name: archive.read(name) for name in archive.namelist()}


_URI_SCHEME = re.compile(r"^[A-Za-z][A-Za-z0-9+.-]*:")


def referenced_files(path: Path) -> list[str]:
    """The files a ``.gltf`` or ``.obj`` at ``path`` refers to that exist under its folder (relative
    names), found as the loader finds them (:class:`~farfield.core.exchange.references.FileIndex`:
    a reference that differs in case or folder from the file is packed under the file's name)."""
    path = Path(path)
    suffix = path.suffix.lower()
    references: list[str] = []
    libraries: set[str] = set()  # an OBJ's material libraries, whose texture maps are references too
    if suffix == ".gltf":
        try:
            document = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError, UnicodeDecodeError):
            return []
        uris = [b.get("uri") for b in document.get("buffers", []) if isinstance(b, dict)] + [
            i.get("uri") for i in document.get("images", []) if isinstance(i, dict)
        ]
        # A URI is percent-encoded (RFC 3986): "my%20file.bin" is the file "my file.bin".
        references = [uri_path(u) for u in uris if isinstance(u, str) and not u.startswith("data:")]
    elif suffix == ".obj":
        from farfield.core.exchange.obj import decode_text, material_libraries, texture_maps

        try:
            references = material_libraries(decode_text(path.read_bytes()))
            libraries = set(references)
        except (OSError, SceneLoadError):
            return []
    index = None
    found: list[str] = []
    while references:
        reference = references.pop(0)
        if _URI_SCHEME.match(reference.strip()) and not re.match(r"^[A-Za-z]:[\\/]", reference.strip()):
            continue  # a data:, file: or http URI (a Windows drive path is a file name)
        index = index or FileIndex.of_folder(path.parent)
        local = index.find(reference)
        if local is None or local in found:
            continue
        found.append(local)
        if suffix == ".obj" and reference in libraries:
            try:
                maps = texture_maps(decode_text((path.parent / local).read_bytes()))
            except (OSError, SceneLoadError):
                continue
            references += [name for files in maps.values() for name in files.values()]
    return [name for name in found if name != path.name]


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
