"""Impostor bundle: a directory of ``manifest.json`` + ``payload.bin`` + (H, W, 4) uint8 ``atlas-NNN.png`` pages + ``impostor.glb``.

The bundle is the on-disk form of one :class:`farfield.core.impostor.impostor.Impostor`.  Format version 2:

``manifest.json``
    UTF-8 JSON object on one line, keys sorted, floats written with Python's shortest round-trip ``repr`` so
    every float64 reads back bit-exact.  Small: the header, one entry per layer and per page, the
    stats and the parameters; no per-quad or per-vertex data.  Keys:

    ``format``
        ``"farfield-impostor"``.
    ``format_version``
        ``2``.  A reader refuses any value but 1 and 2 (version 1: see below).
    ``code_version``
        farfield version that made the impostor (string).
    ``technique``
        the name of the technique that made it (:data:`farfield.core.techniques.TECHNIQUES`).
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
    ``payload``
        What the geometry is and where its arrays lie: ``kind`` (``"quads"`` or ``"mesh"``, see
        :mod:`farfield.core.impostor.impostor`), ``counts`` (``{"quads": q}`` or ``{"vertices": v, "triangles": t}``),
        ``file`` (``"payload.bin"``), ``nbytes`` and ``sha256`` (hex) of that file, and ``arrays``:
        one ``{"name", "dtype", "shape", "offset", "nbytes"}`` per array, in the kind's order.
        ``dtype`` is a little-endian numpy type string: the writer uses ``"<f8"`` for every float
        array and ``"<i4"`` for an integer array whose values fit in int32, else ``"<i8"``; a
        reader accepts ``"<f4"``, ``"<f8"``, ``"<u2"``, ``"<u4"``, ``"<i4"`` and ``"<i8"`` and
        widens to float64 / int64.
    ``pages``
        List of ``{"file": "atlas-000.png", "width": W, "height": H}``, in page order.
    ``channels`` (only where the impostor keeps channels beside its colour)
        ``{"normal": [{"file": "normal-000.png", "width": W, "height": H}, ...]}``: per channel,
        pages laid out as ``pages`` (:data:`farfield.core.impostor.impostor.PAGE_CHANNELS`: world
        normals encoded n * 0.5 + 0.5, linear); a normal entry's ``"alpha": "depth"`` says its
        alpha holds the depth channel (:mod:`farfield.core.impostor.depth`).
    ``glb``
        ``"impostor.glb"``.
    ``stats``, ``parameters``
        JSON objects: counts and memory (not the timings, which differ from run to run: see
        :data:`RUN_DEPENDENT_STATS`); every knob that made the impostor.

``payload.bin``
    The payload's arrays, C order, each at an offset that is a multiple of 8 (the end of the
    previous array rounded up, zero bytes between; the first at 0), nothing after the last one.

    ``"quads"``: ``corners`` (q, 4, 3) world metres, the top-left, top-right, bottom-right and
    bottom-left corners of each quad's texel rectangle in its layer image (a baked layer image's x
    runs right to left as seen from the reference viewpoint: see :mod:`farfield.core.impostor.impostor`); ``uv``
    (q, 4, 2) page coordinates of the same corners in glTF convention ((0, 0) is the top-left of
    the page); ``page`` (q,) atlas page; ``layer`` (q,) layer.

    A kind's optional arrays (``OPTIONAL_ARRAYS``: a points payload's ``normal`` (n, 3), a quads
    payload's ``depth_range`` (q, 2) with the depth channel) follow
    its arrays where the payload keeps them, and are absent (not listed, no bytes) where it does not.

    ``"mesh"``: ``vertices`` (v, 3) world metres; ``uv`` (v, 2) page coordinates, glTF
    convention; ``triangles`` (t, 3) vertex indices; ``page`` (t,) atlas page and ``mesh`` (t,)
    connected component of each triangle.

``atlas-000.png``, ``atlas-001.png``, ...
    8-bit RGBA PNG, top row first, one per atlas page, no metadata chunks.

``impostor.glb``
    The same geometry and pages as glTF 2.0 binary (see :mod:`farfield.core.impostor.glb`), for any glTF viewer.

Format version 1 (read, no longer written) had no ``payload`` and no ``payload.bin``: a ``quads``
object in the manifest held ``count`` and the JSON lists ``corners``, ``uv``, ``page`` and
``layer``, and a TDM's triangle was a quad whose fourth corner repeated its third, its ``layer``
the triangle's mesh.  :func:`read_bundle` gives a version 1 TDM a mesh payload
(:meth:`farfield.core.impostor.impostor.MeshPayload.from_triangle_corners` of the quads' first three corners), any
other version 1 bundle a quad payload.

Equal impostors (and the same zlib) give byte-identical bundles.  :func:`write_bundle` builds the
bundle in a hidden sibling directory and renames it into place, so a reader sees the old bundle
or the new one, never a mix.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import re
import shutil
import tempfile
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image

from farfield.core.errors import BundleFormatError, ConflictError
from farfield.core.impostor.glb import impostor_glb
from farfield.core.impostor.impostor import (
    PAGE_CHANNELS,
    PAYLOAD_KINDS,
    Impostor,
    MeshPayload,
    QuadPayload,
    check_impostor,
)
from farfield.core.impostor.png_pages import PagePngs, map_threads

__all__ = [
    "FORMAT",
    "FORMAT_VERSION",
    "GLB_NAME",
    "MANIFEST_NAME",
    "PAYLOAD_NAME",
    "READABLE_VERSIONS",
    "BundlePaths",
    "bundle_zip",
    "encode_payload",
    "manifest_bytes",
    "channel_file_name",
    "page_file_name",
    "read_bundle",
    "write_bundle",
]

FORMAT = "farfield-impostor"
FORMAT_VERSION = 2
READABLE_VERSIONS = (1, 2)
MANIFEST_NAME = "manifest.json"
PAYLOAD_NAME = "payload.bin"
GLB_NAME = "impostor.glb"

# payload.bin: every array starts at a multiple of this many bytes.
_ALIGNMENT = 8
# dtypes a reader accepts per array kind ("f" float, "i" integer), widened to float64 / int64.
_READ_DTYPES = {"f": ("<f4", "<f8"), "i": ("<u2", "<u4", "<i4", "<i8")}
_INT32 = np.iinfo(np.int32)

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
    payload: Path  # payload.bin


def page_file_name(index: int) -> str:
    """File name of atlas page ``index``.

    >>> page_file_name(0), page_file_name(12)
    ('atlas-000.png', 'atlas-012.png')
    """
    return f"atlas-{index:03d}.png"


def channel_file_name(channel: str, index: int) -> str:
    """File name of page ``index`` of ``channel``.

    >>> channel_file_name("normal", 3)
    'normal-003.png'
    """
    return f"{channel}-{index:03d}.png"


def _json_default(value):
    """numpy scalars and arrays in ``stats``/``parameters``/``layers`` become JSON numbers and lists."""
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"{type(value).__name__} is not JSON-ready: {value!r}")


def _stored_dtype(kind: str, array: np.ndarray) -> str:
    """The little-endian dtype an array is written as: ``<f8`` for floats; ``<i4`` for integers
    that fit in int32, else ``<i8``."""
    if kind == "f":
        return "<f8"
    if array.size == 0 or (array.min() >= _INT32.min and array.max() <= _INT32.max):
        return "<i4"
    return "<i8"


def encode_payload(payload) -> tuple[bytes, dict]:
    """``payload.bin``'s bytes and the manifest's ``payload`` entry for a checked payload.

    >>> from farfield.core.impostor.impostor import QuadPayload
    >>> data, entry = encode_payload(QuadPayload.empty())
    >>> data, entry["kind"], entry["counts"], [(a["name"], a["dtype"], a["shape"]) for a in entry["arrays"]][:2]
    (b'', 'quads', {'quads': 0}, [('corners', '<f8', [0, 4, 3]), ('uv', '<f8', [0, 4, 2])])
    """
    parts: list[bytes] = []
    table = []
    offset = 0
    for name, kind, _ in payload.stored_arrays():  # the kind's arrays, then the optional ones it keeps
        array = getattr(payload, name)
        dtype = _stored_dtype(kind, array)
        data = np.ascontiguousarray(array, dtype=dtype).tobytes()
        pad = -offset % _ALIGNMENT
        parts.append(b"\x00" * pad)
        offset += pad
        table.append({"name": name, "dtype": dtype, "shape": list(array.shape), "offset": offset, "nbytes": len(data)})
        parts.append(data)
        offset += len(data)
    blob = b"".join(parts)
    entry = {
        "kind": payload.kind,
        "counts": payload.counts(),
        "file": PAYLOAD_NAME,
        "nbytes": len(blob),
        "sha256": hashlib.sha256(blob).hexdigest(),
        "arrays": table,
    }
    return blob, entry


# Statistics that differ between two runs of the same bake (seconds per stage): reported by the CLI,
# the cell's record and the job, never written into a bundle, so equal inputs give equal bytes.
RUN_DEPENDENT_STATS = ("seconds",)


def stored_stats(stats: dict) -> dict:
    """``stats`` as a bundle stores them: without :data:`RUN_DEPENDENT_STATS`.

    >>> stored_stats({"quads": 3, "seconds": {"total": 0.5}})
    {'quads': 3}
    """
    return {k: v for k, v in stats.items() if k not in RUN_DEPENDENT_STATS}


def _manifest(impostor: Impostor, payload_entry: dict) -> dict:
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
        "payload": payload_entry,
        "pages": [
            {"file": page_file_name(index), "width": int(page.shape[1]), "height": int(page.shape[0])}
            for index, page in enumerate(impostor.pages)
        ],
        "glb": GLB_NAME,
        "stats": stored_stats(impostor.stats),
        "parameters": impostor.parameters,
    } | (
        {
            "channels": {
                name: [
                    {"file": channel_file_name(name, i), "width": int(p.shape[1]), "height": int(p.shape[0])}
                    | _alpha_entry(impostor, name)
                    for i, p in enumerate(pages)
                ]
                for name, pages in sorted(impostor.channels.items())
            }
        }
        if impostor.channels
        else {}
    )


def _alpha_entry(impostor: Impostor, channel: str) -> dict:
    """What a channel page's alpha holds where it is not 255 inside a tile: ``{"alpha": "depth"}``
    for the normal pages of an impostor with the depth channel (:mod:`farfield.core.impostor.depth`)."""
    from farfield.core.impostor.depth import keeps_depth

    return {"alpha": "depth"} if channel == "normal" and keeps_depth(impostor) else {}


def _manifest_bytes(impostor: Impostor, payload_entry: dict) -> bytes:
    try:
        text = json.dumps(
            _manifest(impostor, payload_entry),
            sort_keys=True,
            separators=(",", ":"),
            allow_nan=False,
            default=_json_default,
        )
    except (TypeError, ValueError) as error:
        raise BundleFormatError(f"{MANIFEST_NAME}: impostor is not JSON-ready: {error}") from error
    return (text + "\n").encode("utf-8")


def manifest_bytes(impostor: Impostor) -> bytes:
    """The UTF-8 bytes of ``manifest.json`` for ``impostor``, keys sorted, newline-terminated.

    Raises
    ------
    BundleFormatError
        The impostor's arrays do not fit, or a dict field holds something JSON cannot write
        (an object, NaN, infinity).
    """
    check_impostor(impostor)
    return _manifest_bytes(impostor, encode_payload(impostor.payload)[1])


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


_BUNDLE_ENTRY = re.compile(
    rf"{re.escape(MANIFEST_NAME)}|{re.escape(PAYLOAD_NAME)}|{re.escape(GLB_NAME)}|atlas-\d+\.png"
    rf"|(?:{'|'.join(PAGE_CHANNELS)})-\d+\.png"  # a channel's pages (channel_file_name)
)


def check_destination(directory: str | os.PathLike) -> None:
    """Refuse a folder that :func:`write_bundle` would replace but that is not a bundle: a user's
    ``--out`` pointing at a folder of other files (the scene itself, say) would lose them all.

    Accepted: a path that does not exist yet (in a folder this process may write), an empty folder,
    or a bundle to replace (a ``manifest.json`` of this format and nothing but bundle files).
    Refused (:class:`ConflictError`): a file, the current folder or one above it, and any other
    folder with something in it.
    """
    path = Path(directory)
    where = path.resolve()
    if where == Path.cwd().resolve() or where in Path.cwd().resolve().parents:
        raise ConflictError(
            f"{directory}: the current folder or one above it would be replaced by the bundle; give a folder of its own"
        )
    if not path.exists():
        parent = next(p for p in where.parents if p.exists())  # the folder that will hold it, made on writing
        if not (parent.is_dir() and os.access(parent, os.W_OK | os.X_OK)):
            raise BundleFormatError(
                f"{directory}: cannot write a bundle there: {parent} is not a folder this process may write"
            )
        return
    if not path.is_dir():
        raise ConflictError(f"{directory}: is a file, not a bundle folder; give a new or empty folder")
    entries = sorted(p.name for p in path.iterdir())
    if not entries:
        return
    try:
        bundle = json.loads((path / MANIFEST_NAME).read_bytes()).get("format") == FORMAT
    except (OSError, ValueError, AttributeError):
        bundle = False
    others = [e for e in entries if not _BUNDLE_ENTRY.fullmatch(e)]
    if bundle and not others:
        return

    def shown(names: list[str]) -> str:
        return ", ".join(names[:3]) + (f", ... ({len(names)} in all)" if len(names) > 3 else "")

    what = f"holds files no bundle has ({shown(others)})" if bundle else f"is not a bundle (it holds {shown(entries)})"
    raise ConflictError(
        f"{directory}: exists and {what}; the bundle would replace it whole: give a new or empty folder, or an earlier bundle's"
    )


def write_bundle(
    impostor: Impostor, directory: str | os.PathLike, *, sync: bool = True, workers: int | None = None
) -> BundlePaths:
    """Write ``impostor`` as a bundle directory, replacing any file or directory already there.

    Parameters
    ----------
    impostor : Impostor
        The impostor; its arrays must pass :func:`farfield.core.impostor.impostor.check_impostor`.
    directory : path
        The bundle directory to create.  Its parent is created if missing.
    sync : bool
        Flush each file to the disk (``fsync``) before the bundle is renamed into place.  False for
        a bundle written only to be handed on (a service worker's, published to the blob store).
    workers : int, optional
        Threads that encode the pages and write (and sync) the files
        (:func:`farfield.core.impostor.png_pages.thread_count` by default); 1 does it all in the
        calling thread.  The bytes do not depend on it.  Each page is encoded once, for its file and
        for the GLB.

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
    check_impostor(impostor)
    payload, payload_entry = encode_payload(impostor.payload)
    files = {MANIFEST_NAME: _manifest_bytes(impostor, payload_entry), PAYLOAD_NAME: payload}
    named = [(page_file_name(index), page) for index, page in enumerate(impostor.pages)]
    for name, pages in sorted(impostor.channels.items()):
        named += [(channel_file_name(name, index), page) for index, page in enumerate(pages)]
    pngs = PagePngs(workers)
    files.update(zip([name for name, _ in named], pngs.encode([page for _, page in named])))
    files[GLB_NAME] = impostor_glb(impostor, pngs)

    try:
        destination.parent.mkdir(parents=True, exist_ok=True)
        staging = Path(tempfile.mkdtemp(prefix=f".{destination.name}.tmp-", dir=destination.parent))
    except OSError as error:
        raise BundleFormatError(f"{destination}: cannot write a bundle there: {error.strerror or error}") from error
    try:
        # Several files at a time: a thread waiting on fsync holds no core, and the file system
        # commits concurrent syncs together (15 files: 0.01-0.04 s against 0.06-0.09 s one by one).
        write = _write_file if sync else Path.write_bytes
        map_threads(lambda item: write(staging / item[0], item[1]), list(files.items()), pngs.workers)
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
        payload=destination / PAYLOAD_NAME,
    )


def _read_manifest(directory: Path) -> dict:
    path = directory / MANIFEST_NAME
    try:
        text = path.read_bytes().decode("utf-8")
    except FileNotFoundError as error:
        inner = sorted(p.parent for p in directory.glob(f"*/{MANIFEST_NAME}")) if directory.is_dir() else []
        if inner:  # a folder of bundles, e.g. `farfield bake --instances`: one per prototype
            names = ", ".join(str(p) for p in inner[:5]) + (", ..." if len(inner) > 5 else "")
            raise BundleFormatError(
                f"{path}: missing, not a bundle; the folder holds {len(inner)} bundle{'s' if len(inner) > 1 else ''}: {names} (give one)"
            ) from error
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
    version = manifest.get("format_version")
    if isinstance(version, bool) or version not in READABLE_VERSIONS:
        raise BundleFormatError(
            f"{path}: format_version {version!r} is not supported "
            f"(this reader knows {', '.join(map(str, READABLE_VERSIONS))})"
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
        raise BundleFormatError(f"{path}: image is {page.shape[1]}x{page.shape[0]}, manifest says {width}x{height}")
    return page


def _image_entries(entries, path: Path, where: str, file_name) -> list[tuple[str, int, int]]:
    """A manifest list of page images (``pages``, or a channel's) as [(file, width, height)]: each
    ``{"file": file_name(index), "width": W, "height": H}`` with W, H >= 1."""
    if not isinstance(entries, list):
        raise BundleFormatError(f"{path}: {where} is a {type(entries).__name__}, expected a list")
    result = []
    for index, entry in enumerate(entries):
        name = entry.get("file") if isinstance(entry, dict) else None
        width = entry.get("width") if isinstance(entry, dict) else None
        height = entry.get("height") if isinstance(entry, dict) else None
        if (
            name != file_name(index)
            or not isinstance(width, int)
            or not isinstance(height, int)
            or width < 1
            or height < 1
        ):
            raise BundleFormatError(
                f"{path}: {where}[{index}] is {entry!r}, expected "
                f"{{'file': {file_name(index)!r}, 'width': W, 'height': H}}"
            )
        result.append((name, width, height))
    return result


def _page_entries(manifest: dict, path: Path) -> list[tuple[str, int, int]]:
    return _image_entries(_field(manifest, path, "pages"), path, "pages", page_file_name)


def _channel_entries(manifest: dict, path: Path) -> dict[str, list[tuple[str, int, int]]]:
    """The manifest's ``channels`` (absent: none) as name -> [(file, width, height)] per page."""
    from farfield.core.impostor.impostor import PAGE_CHANNELS

    channels = manifest.get("channels", {})
    if not isinstance(channels, dict):
        raise BundleFormatError(f"{path}: channels is a {type(channels).__name__}, expected an object")
    unknown = sorted(set(channels) - set(PAGE_CHANNELS))
    if unknown:
        raise BundleFormatError(f"{path}: channels has {unknown[0]!r}, expected one of {list(PAGE_CHANNELS)}")
    return {
        name: _image_entries(entries, path, f"channels.{name}", lambda i, name=name: channel_file_name(name, i))
        for name, entries in channels.items()
    }


def _payload_v1(manifest: dict, path: Path):
    """A version 1 manifest's ``quads``: a quad payload, or for a technique that bakes meshes (the
    TDM, whose triangles were quads with the fourth corner repeating the third) the mesh payload of
    those triangles."""
    from farfield.core.techniques import (
        TECHNIQUES,  # here: only a version 1 bundle needs the registry (it imports every technique)
    )

    count = _field(manifest, path, "quads", "count")
    if isinstance(count, bool) or not isinstance(count, int) or count < 0:
        raise BundleFormatError(f"{path}: quads.count is {count!r}, expected a count")
    corners = _array(manifest, path, (count, 4, 3), np.float64, "quads", "corners")
    uv = _array(manifest, path, (count, 4, 2), np.float64, "quads", "uv")
    page = _array(manifest, path, (count,), np.int64, "quads", "page")
    layer = _array(manifest, path, (count,), np.int64, "quads", "layer")
    if (
        getattr(TECHNIQUES.get(manifest.get("technique")), "payload_kind", None) == MeshPayload.kind
        and np.array_equal(corners[:, 3], corners[:, 2])
        and np.array_equal(uv[:, 3], uv[:, 2])
    ):
        return MeshPayload.from_triangle_corners(corners[:, :3], uv[:, :3], page=page, mesh=layer)
    return QuadPayload(corners=corners, uv=uv, page=page, layer=layer)


def _is_count(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0


def _payload_v2(manifest: dict, root: Path, path: Path):
    """The payload a version 2 manifest describes, read from ``payload.bin`` (see the module docstring)."""
    kind = _field(manifest, path, "payload", "kind")
    if isinstance(kind, str) and kind not in PAYLOAD_KINDS:  # a technique's own kind registers with the technique
        import farfield.core.techniques  # noqa: F401
    cls = PAYLOAD_KINDS.get(kind) if isinstance(kind, str) else None
    if cls is None:
        raise BundleFormatError(f"{path}: payload.kind is {kind!r}, expected one of {sorted(PAYLOAD_KINDS)}")
    if _field(manifest, path, "payload", "file") != PAYLOAD_NAME:
        raise BundleFormatError(f"{path}: payload.file is {manifest['payload']['file']!r}, expected {PAYLOAD_NAME!r}")
    nbytes = _field(manifest, path, "payload", "nbytes")
    digest = _field(manifest, path, "payload", "sha256")
    table = _field(manifest, path, "payload", "arrays")
    counts = _field(manifest, path, "payload", "counts")
    if (
        not _is_count(nbytes)
        or not isinstance(digest, str)
        or not isinstance(table, list)
        or not isinstance(counts, dict)
    ):
        raise BundleFormatError(f"{path}: payload needs a byte count, a sha256, an arrays list and counts")
    names = [name for name, _, _ in cls.ARRAYS]
    listed = [entry.get("name") if isinstance(entry, dict) else None for entry in table]
    # After the kind's arrays, the optional ones it keeps (cls.OPTIONAL_ARRAYS), in their order.
    specs = list(cls.ARRAYS) + [spec for spec in cls.OPTIONAL_ARRAYS if spec[0] in listed[len(names) :]]
    if listed != [name for name, _, _ in specs]:
        optional = [name for name, _, _ in cls.OPTIONAL_ARRAYS]
        raise BundleFormatError(
            f"{path}: payload.arrays must list a {kind} payload's arrays {names}, in this order"
            + (f", then any of {optional}" if optional else "")
        )
    binary = root / PAYLOAD_NAME
    try:
        data = binary.read_bytes()
    except FileNotFoundError as error:
        raise BundleFormatError(f"{binary}: missing") from error
    except OSError as error:
        raise BundleFormatError(f"{binary}: unreadable: {error}") from error
    if len(data) != nbytes or hashlib.sha256(data).hexdigest() != digest:
        raise BundleFormatError(
            f"{binary}: {len(data)} bytes that do not match the manifest's payload ({nbytes} bytes, sha256 {digest})"
        )
    arrays = {}
    offset = 0
    for entry, (name, kind_of, _) in zip(table, specs):
        dtype, shape, start, size = entry.get("dtype"), entry.get("shape"), entry.get("offset"), entry.get("nbytes")
        offset += -offset % _ALIGNMENT
        if (
            dtype not in _READ_DTYPES[kind_of]
            or not isinstance(shape, list)
            or not all(_is_count(n) for n in shape)
            or start != offset
            or not _is_count(size)
            or size != int(np.prod(shape, dtype=np.int64)) * np.dtype(dtype).itemsize
        ):
            raise BundleFormatError(
                f"{path}: payload.arrays entry {entry!r} does not fit (dtype one of "
                f"{list(_READ_DTYPES[kind_of])}, shape a list of counts, offset {offset}, nbytes = size x item size)"
            )
        if offset + size > len(data):
            raise BundleFormatError(
                f"{path}: payload.arrays {name} runs past the end of {PAYLOAD_NAME} ({len(data)} bytes)"
            )
        array = np.frombuffer(data, dtype=dtype, count=size // np.dtype(dtype).itemsize, offset=offset).reshape(shape)
        arrays[name] = array.astype(np.float64 if kind_of == "f" else np.int64)  # a writable native copy
        offset += size
    if offset != len(data):
        raise BundleFormatError(f"{path}: payload.arrays end at byte {offset} of {PAYLOAD_NAME}'s {len(data)}")
    payload = cls.from_arrays(arrays)
    if payload.counts() != counts:
        raise BundleFormatError(f"{path}: payload.counts is {counts!r}, the arrays hold {payload.counts()!r}")
    return payload


def read_bundle(directory: str | os.PathLike) -> Impostor:
    """Read the impostor stored in a bundle directory (format version 2, or 1).

    Parameters
    ----------
    directory : path
        A directory written by :func:`write_bundle` (or by a version 1 writer).

    Returns
    -------
    Impostor
        Arrays bit-equal to those written: float64 coordinates, UVs and viewpoint, int64 indices,
        (H, W, 4) uint8 pages.  numpy scalars in ``stats``, ``parameters`` and ``layers`` come
        back as Python numbers, arrays as lists.

    Raises
    ------
    BundleFormatError
        A missing file, JSON that does not parse, an unknown ``format`` or ``format_version``,
        a payload file that disagrees with the manifest, arrays or images whose shapes disagree
        with the manifest.  The message names the file.
    """
    root = Path(directory)
    manifest = _read_manifest(root)
    path = root / MANIFEST_NAME
    if manifest["format_version"] == 1:
        payload = _payload_v1(manifest, path)
    else:
        payload = _payload_v2(manifest, root, path)
    viewpoint = _array(manifest, path, (3,), np.float64, "reference_viewpoint")
    if _field(manifest, path, "glb") != GLB_NAME:
        raise BundleFormatError(f"{path}: glb is {manifest['glb']!r}, expected {GLB_NAME!r}")
    glb = root / GLB_NAME
    if not glb.is_file():
        raise BundleFormatError(f"{glb}: missing")
    pages = tuple(_read_page(root / name, width, height) for name, width, height in _page_entries(manifest, path))
    channels = {
        channel: tuple(_read_page(root / name, width, height) for name, width, height in entries)
        for channel, entries in _channel_entries(manifest, path).items()
    }
    impostor = Impostor(
        technique=_field(manifest, path, "technique"),
        viewcell=_field(manifest, path, "viewcell"),
        reference_viewpoint=viewpoint,
        resolution=_field(manifest, path, "resolution"),
        fov_deg=_field(manifest, path, "fov_deg"),
        pages=pages,
        payload=payload,
        layers=_field(manifest, path, "layers"),
        stats=_field(manifest, path, "stats"),
        parameters=_field(manifest, path, "parameters"),
        code_version=_field(manifest, path, "code_version"),
        channels=channels,
    )
    try:
        check_impostor(impostor)
    except BundleFormatError as error:
        raise BundleFormatError(f"{path}: {error}") from error
    return impostor


def bundle_zip(directory: str | os.PathLike) -> bytes:
    """Deterministic zip bytes of a bundle: its manifest, payload file (version 2), pages and GLB at
    the archive's top level.

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
    names += [name for entries in _channel_entries(manifest, path).values() for name, _, _ in entries]
    if manifest["format_version"] >= 2:
        names.append(PAYLOAD_NAME)
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
