"""Impostor bundle: a directory of ``manifest.json`` + (H, W, 4) uint8 ``atlas-NNN.png`` pages + ``impostor.glb``.

The bundle is the on-disk form of one :class:`core.impostor.Impostor`.  Format version 1:

``manifest.json``
    UTF-8 JSON object on one line, keys sorted, floats written with Python's shortest round-trip ``repr`` so
    every float64 reads back bit-exact.  Keys:

    ``format``
        ``"farfield-impostor"``.
    ``format_version``
        ``1``.  A reader refuses any other value.
    ``code_version``
        farfield version that made the impostor (string).
    ``technique``
        ``"layered"``, ``"envmap"``, ``"tdm"``, ``"points"``, ``"ldi"`` or ``"billboard"``.
    ``viewcell``
        The view cell's JSON description (``{"kind": "box", "lo", "hi"}`` or
        ``{"kind": "shaft", "apex", "direction", "apex_angle_deg", "min_distance",
        "max_distance"}``), world metres.
    ``reference_viewpoint``
        ``[x, y, z]`` world metres.
    ``resolution``
        Output image pixels per side the impostor was made for (integer).
    ``fov_deg``
        Output field of view, degrees.
    ``layers``
        List of one object per layer, as the technique recorded it (distance, depth range in eye
        depth, texels kept, ...).
    ``quads``
        Columns of the q quads: ``count`` (q); ``corners`` (q, 4, 3) world metres, top-left,
        top-right, bottom-right, bottom-left as seen from the reference viewpoint; ``uv``
        (q, 4, 2) page coordinates in glTF convention ((0, 0) is the top-left of the page);
        ``page`` (q,) atlas page index; ``layer`` (q,) layer index.
    ``pages``
        List of ``{"file": "atlas-000.png", "width": W, "height": H}``, in page order.
    ``glb``
        ``"impostor.glb"``.
    ``stats``, ``parameters``
        JSON objects: counts, memory and timings; every knob that made the impostor.

``atlas-000.png``, ``atlas-001.png``, ...
    8-bit RGBA PNG, top row first, one per atlas page, no metadata chunks.

``impostor.glb``
    The same quads and pages as glTF 2.0 binary (see :mod:`core.glb`), for any glTF viewer.

Equal impostors (and the same zlib) give byte-identical bundles.  :func:`write_bundle` builds the
bundle in a hidden sibling directory and renames it into place, so a reader sees the old bundle
or the new one, never a mix.
"""

from __future__ import annotations

import io
import json
import os
import shutil
import tempfile
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image

from core.errors import BundleFormatError
from core.glb import impostor_glb, page_png
from core.impostor import Impostor, check_impostor

__all__ = [
    "FORMAT",
    "FORMAT_VERSION",
    "GLB_NAME",
    "MANIFEST_NAME",
    "BundlePaths",
    "bundle_zip",
    "manifest_bytes",
    "page_file_name",
    "read_bundle",
    "write_bundle",
]

FORMAT = "farfield-impostor"
FORMAT_VERSION = 1
MANIFEST_NAME = "manifest.json"
GLB_NAME = "impostor.glb"

# A fixed, valid DOS timestamp (the zip epoch) so archives do not depend on file times.
_ZIP_DATE_TIME = (1980, 1, 1, 0, 0, 0)
_ZIP_COMPRESS_LEVEL = 6
# Attempts to swap a bundle into place when another writer replaces the same destination meanwhile.
_REPLACE_ATTEMPTS = 3


@dataclass(frozen=True, slots=True)
class BundlePaths:
    """Where :func:`write_bundle` put each file of one bundle."""

    directory: Path
    manifest: Path
    pages: tuple[Path, ...]  # (p,) atlas-NNN.png in page order
    glb: Path


def page_file_name(index: int) -> str:
    """File name of atlas page ``index``.

    >>> page_file_name(0), page_file_name(12)
    ('atlas-000.png', 'atlas-012.png')
    """
    return f"atlas-{index:03d}.png"


def _json_default(value):
    """numpy scalars and arrays in ``stats``/``parameters``/``layers`` become JSON numbers and lists."""
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"{type(value).__name__} is not JSON-ready: {value!r}")


def _manifest(impostor: Impostor) -> dict:
    return {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "code_version": impostor.code_version,
        "technique": impostor.technique,
        "viewcell": impostor.viewcell,
        "reference_viewpoint": np.asarray(impostor.reference_viewpoint, dtype=np.float64).tolist(),
        "resolution": int(impostor.resolution),
        "fov_deg": float(impostor.fov_deg),
        "layers": impostor.layers,
        "quads": {
            "count": impostor.quad_count,
            "corners": np.asarray(impostor.quad_corners, dtype=np.float64).tolist(),
            "uv": np.asarray(impostor.quad_uv, dtype=np.float64).tolist(),
            "page": np.asarray(impostor.quad_page, dtype=np.int64).tolist(),
            "layer": np.asarray(impostor.quad_layer, dtype=np.int64).tolist(),
        },
        "pages": [
            {"file": page_file_name(index), "width": int(page.shape[1]), "height": int(page.shape[0])}
            for index, page in enumerate(impostor.pages)
        ],
        "glb": GLB_NAME,
        "stats": impostor.stats,
        "parameters": impostor.parameters,
    }


def manifest_bytes(impostor: Impostor) -> bytes:
    """The UTF-8 bytes of ``manifest.json`` for ``impostor``, keys sorted, newline-terminated.

    Raises
    ------
    BundleFormatError
        The impostor's arrays do not fit, or a dict field holds something JSON cannot write
        (an object, NaN, infinity).
    """
    check_impostor(impostor)
    try:
        text = json.dumps(
            _manifest(impostor),
            sort_keys=True,
            separators=(",", ":"),
            allow_nan=False,
            default=_json_default,
        )
    except (TypeError, ValueError) as error:
        raise BundleFormatError(f"{MANIFEST_NAME}: impostor is not JSON-ready: {error}") from error
    return (text + "\n").encode("utf-8")


def _write_file(path: Path, data: bytes) -> None:
    with open(path, "wb") as handle:
        handle.write(data)
        handle.flush()
        os.fsync(handle.fileno())


def _swap_into_place(staging: Path, destination: Path) -> None:
    """Rename ``staging`` to ``destination``, replacing whatever is there whole."""
    for _ in range(_REPLACE_ATTEMPTS):
        try:
            os.rename(staging, destination)
            return
        except OSError:
            if not os.path.lexists(destination):
                raise
        # Something is there (an old bundle, a file, another writer's bundle).  Rename it aside
        # (atomic) rather than delete it in place, so no reader ever sees it half removed.
        aside = Path(tempfile.mkdtemp(prefix=f".{destination.name}.old-", dir=destination.parent))
        try:
            os.rename(destination, aside / "old")
        except FileNotFoundError:
            pass  # another writer moved it first; the next attempt renames ours into place
        finally:
            shutil.rmtree(aside)
    raise BundleFormatError(f"{destination}: could not replace it in {_REPLACE_ATTEMPTS} attempts")


def write_bundle(impostor: Impostor, directory: str | os.PathLike) -> BundlePaths:
    """Write ``impostor`` as a bundle directory, replacing any file or directory already there.

    Parameters
    ----------
    impostor : Impostor
        The impostor; its arrays must pass :func:`core.impostor.check_impostor`.
    directory : path
        The bundle directory to create.  Its parent is created if missing.

    Returns
    -------
    BundlePaths
        The files written.

    Raises
    ------
    BundleFormatError
        The impostor cannot be written (bad shapes or dtypes, dict fields that are not JSON).
        Nothing is left at ``directory`` (an existing bundle there stays as it was).
    """
    destination = Path(directory)
    # Everything is encoded before touching the disk, so a bad impostor creates nothing.
    files = {MANIFEST_NAME: manifest_bytes(impostor)}
    for index, page in enumerate(impostor.pages):
        files[page_file_name(index)] = page_png(page)
    files[GLB_NAME] = impostor_glb(impostor)

    destination.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{destination.name}.tmp-", dir=destination.parent))
    try:
        for name, data in files.items():
            _write_file(staging / name, data)
        os.chmod(staging, 0o755)  # mkdtemp makes it 0o700; a bundle is as readable as any file
        _swap_into_place(staging, destination)
    finally:
        if staging.exists():
            shutil.rmtree(staging)
    return BundlePaths(
        directory=destination,
        manifest=destination / MANIFEST_NAME,
        pages=tuple(destination / page_file_name(i) for i in range(len(impostor.pages))),
        glb=destination / GLB_NAME,
    )


def _read_manifest(directory: Path) -> dict:
    path = directory / MANIFEST_NAME
    try:
        text = path.read_bytes().decode("utf-8")
    except FileNotFoundError as error:
        raise BundleFormatError(f"{path}: missing, not a bundle") from error
    except (OSError, UnicodeDecodeError) as error:
        raise BundleFormatError(f"{path}: unreadable: {error}") from error
    try:
        manifest = json.loads(text)
    except ValueError as error:
        raise BundleFormatError(f"{path}: not JSON: {error}") from error
    if not isinstance(manifest, dict):
        raise BundleFormatError(f"{path}: a JSON {type(manifest).__name__}, expected an object")
    if manifest.get("format") != FORMAT:
        raise BundleFormatError(f"{path}: format is {manifest.get('format')!r}, expected {FORMAT!r}")
    if manifest.get("format_version") != FORMAT_VERSION:
        raise BundleFormatError(
            f"{path}: format_version {manifest.get('format_version')!r} is not supported "
            f"(this reader knows {FORMAT_VERSION})"
        )
    return manifest


def _field(manifest: dict, path: Path, *keys: str):
    value = manifest
    for key in keys:
        if not isinstance(value, dict) or key not in value:
            raise BundleFormatError(f"{path}: missing key {'.'.join(keys)!r}")
        value = value[key]
    return value


def _array(manifest: dict, path: Path, shape: tuple[int, ...], dtype, *keys: str) -> np.ndarray:
    """The manifest list at ``keys`` as an array of ``shape`` (``-1`` taken from the data)."""
    value = _field(manifest, path, *keys)
    try:
        array = np.array(value, dtype=dtype)
    except (TypeError, ValueError) as error:
        raise BundleFormatError(f"{path}: {'.'.join(keys)} is not a numeric array: {error}") from error
    if array.size == 0 and array.shape == (0,):
        array = array.reshape((0,) + shape[1:])  # an empty JSON list has lost its trailing axes
    if array.ndim != len(shape) or any(s not in (-1, a) for s, a in zip(shape, array.shape)):
        raise BundleFormatError(f"{path}: {'.'.join(keys)} has shape {array.shape}, expected {shape}")
    return array


def _read_page(path: Path, width: int, height: int) -> np.ndarray:
    try:
        with Image.open(path) as image:
            image.load()
            if image.mode != "RGBA":
                raise BundleFormatError(f"{path}: PNG mode {image.mode}, expected RGBA")
            if image.format != "PNG":
                raise BundleFormatError(f"{path}: {image.format} image, expected PNG")
            page = np.array(image, dtype=np.uint8)
    except FileNotFoundError as error:
        raise BundleFormatError(f"{path}: missing atlas page") from error
    except (OSError, SyntaxError, ValueError, Image.DecompressionBombError) as error:
        # Pillow reports truncated or corrupt data as OSError, SyntaxError or ValueError.
        raise BundleFormatError(f"{path}: unreadable PNG: {error}") from error
    if page.shape != (height, width, 4):
        raise BundleFormatError(
            f"{path}: image is {page.shape[1]}x{page.shape[0]}, manifest says {width}x{height}"
        )
    return page


def _page_entries(manifest: dict, path: Path) -> list[tuple[str, int, int]]:
    entries = _field(manifest, path, "pages")
    if not isinstance(entries, list):
        raise BundleFormatError(f"{path}: pages is a {type(entries).__name__}, expected a list")
    result = []
    for index, entry in enumerate(entries):
        name = entry.get("file") if isinstance(entry, dict) else None
        width = entry.get("width") if isinstance(entry, dict) else None
        height = entry.get("height") if isinstance(entry, dict) else None
        if (
            name != page_file_name(index)
            or not isinstance(width, int)
            or not isinstance(height, int)
            or width < 1
            or height < 1
        ):
            raise BundleFormatError(
                f"{path}: pages[{index}] is {entry!r}, expected "
                f"{{'file': {page_file_name(index)!r}, 'width': W, 'height': H}}"
            )
        result.append((name, width, height))
    return result


def read_bundle(directory: str | os.PathLike) -> Impostor:
    """Read the impostor stored in a bundle directory.

    Parameters
    ----------
    directory : path
        A directory written by :func:`write_bundle`.

    Returns
    -------
    Impostor
        Arrays bit-equal to those written: float64 corners, UVs and viewpoint, int64 page and
        layer indices, (H, W, 4) uint8 pages.  numpy scalars in ``stats``, ``parameters`` and
        ``layers`` come back as Python numbers, arrays as lists.

    Raises
    ------
    BundleFormatError
        A missing file, JSON that does not parse, an unknown ``format`` or ``format_version``,
        arrays or images whose shapes disagree with the manifest.  The message names the file.
    """
    root = Path(directory)
    manifest = _read_manifest(root)
    path = root / MANIFEST_NAME
    count = _field(manifest, path, "quads", "count")
    if not isinstance(count, int) or count < 0:
        raise BundleFormatError(f"{path}: quads.count is {count!r}, expected a count")
    corners = _array(manifest, path, (count, 4, 3), np.float64, "quads", "corners")
    uv = _array(manifest, path, (count, 4, 2), np.float64, "quads", "uv")
    quad_page = _array(manifest, path, (count,), np.int64, "quads", "page")
    quad_layer = _array(manifest, path, (count,), np.int64, "quads", "layer")
    viewpoint = _array(manifest, path, (3,), np.float64, "reference_viewpoint")
    if _field(manifest, path, "glb") != GLB_NAME:
        raise BundleFormatError(f"{path}: glb is {manifest['glb']!r}, expected {GLB_NAME!r}")
    glb = root / GLB_NAME
    if not glb.is_file():
        raise BundleFormatError(f"{glb}: missing")
    pages = tuple(_read_page(root / name, width, height) for name, width, height in _page_entries(manifest, path))
    impostor = Impostor(
        technique=_field(manifest, path, "technique"),
        viewcell=_field(manifest, path, "viewcell"),
        reference_viewpoint=viewpoint,
        resolution=_field(manifest, path, "resolution"),
        fov_deg=_field(manifest, path, "fov_deg"),
        quad_corners=corners,
        quad_uv=uv,
        quad_page=quad_page,
        quad_layer=quad_layer,
        pages=pages,
        layers=_field(manifest, path, "layers"),
        stats=_field(manifest, path, "stats"),
        parameters=_field(manifest, path, "parameters"),
        code_version=_field(manifest, path, "code_version"),
    )
    try:
        check_impostor(impostor)
    except BundleFormatError as error:
        raise BundleFormatError(f"{path}: {error}") from error
    return impostor


def bundle_zip(directory: str | os.PathLike) -> bytes:
    """Deterministic zip bytes of a bundle: its manifest, pages and GLB at the archive's top level.

    Only the files the manifest names are archived, sorted by name, with a fixed timestamp,
    permissions 0644 and deflate level 6, so equal bundles give byte-identical archives.

    Raises
    ------
    BundleFormatError
        ``directory`` is not a readable bundle (see :func:`read_bundle`'s checks on the manifest)
        or a file it names is missing.
    """
    root = Path(directory)
    manifest = _read_manifest(root)
    path = root / MANIFEST_NAME
    names = [MANIFEST_NAME, GLB_NAME] + [name for name, _, _ in _page_entries(manifest, path)]
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        for name in sorted(names):
            try:
                data = (root / name).read_bytes()
            except OSError as error:
                raise BundleFormatError(f"{root / name}: unreadable: {error}") from error
            info = zipfile.ZipInfo(name, date_time=_ZIP_DATE_TIME)
            info.compress_type = zipfile.ZIP_DEFLATED
            info.create_system = 3  # Unix, so external_attr holds POSIX permissions everywhere
            info.external_attr = 0o100644 << 16
            archive.writestr(info, data, compresslevel=_ZIP_COMPRESS_LEVEL)
    return buffer.getvalue()
