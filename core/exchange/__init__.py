"""Scene files -> :class:`farfield.core.scene.Scene`: a registry of loaders keyed by lower-case extension.

One module per format family (``gltf``, ``obj``, ``ply``, ``stl``), each with ``EXTENSIONS`` and
``load(data, extension, name, resolver) -> (objects, warnings)``, after trimesh's ``exchange``.
:func:`load_scene` reads a file (referenced MTL and texture files from its folder);
:func:`load_scene_bytes` reads uploaded bytes (referenced files from ``assets``).  Objects come
sorted by name (trimesh's node order is an implementation detail).

Sidedness: glTF states it per material (``doubleSided``) and is read as it says.  OBJ, PLY and STL
state none; their objects are one-sided by default (``sides="one"``, as engines and three.js's
loaders draw them) or double-sided with ``sides="both"`` (:mod:`farfield.core.sidedness`): the
``sides`` argument of :func:`load_scene` and :func:`load_scene_bytes`, which formats that state
their sidedness ignore.

Every failure is a typed :class:`farfield.core.errors.FarfieldError` whose message starts with the file's
name; recoverable problems (a missing texture) are warnings: emitted as :class:`SceneWarning`
and kept in ``Scene.warnings``.
"""

from __future__ import annotations

import warnings as _warnings
from collections.abc import Callable, Mapping
from pathlib import Path

from trimesh.resolvers import Resolver

from farfield.core.errors import FarfieldError, SceneLoadError, SceneNotFoundError
from farfield.core.exchange import gltf, obj, ply, stl
from farfield.core.exchange.limits import DEFAULT_LIMITS, SceneLimits
from farfield.core.exchange.trimesh_scene import asset_resolver
from farfield.core.scene import Scene, SceneObject, SceneWarning
from farfield.core.sidedness import DEFAULT_SIDES, SIDES, double_sided

Loader = Callable[
    ..., tuple[tuple[SceneObject, ...], tuple[str, ...]]
]  # (data, extension, name, resolver, limits[, sides])

# Lower-case extension without the dot -> loader.
LOADERS: dict[str, Loader] = {
    extension: module.load for module in (gltf, obj, ply, stl) for extension in module.EXTENSIONS
}
# The extensions of formats that state no sidedness: their loaders take the ``sides`` option.
SIDES_OPTION: frozenset[str] = frozenset(
    extension
    for module in (gltf, obj, ply, stl)
    if getattr(module, "SIDES_OPTION", False)
    for extension in module.EXTENSIONS
)

__all__ = [
    "DEFAULT_LIMITS",
    "DEFAULT_SIDES",
    "LOADERS",
    "SIDES",
    "SIDES_OPTION",
    "SceneLimits",
    "load_scene",
    "load_scene_bytes",
    "supported_extensions",
]


def supported_extensions() -> tuple[str, ...]:
    """The extensions :func:`load_scene` reads, sorted, without dots."""
    return tuple(sorted(LOADERS))


def _extension(extension: str, name: str) -> str:
    """``extension`` lower case without the dot, checked against the registry."""
    key = extension.lower().lstrip(".")
    if key not in LOADERS:
        shown = f"'.{key}'" if key else "no extension"
        raise SceneLoadError(
            f"{name}: unsupported scene format {shown}; supported: "
            + ", ".join("." + e for e in supported_extensions())
        )
    return key


def _load(data: bytes, extension: str, name: str, resolver: Resolver, limits: SceneLimits, sides: str) -> Scene:
    """Run the loader for ``extension`` (with ``sides`` where the format states no sidedness);
    prefix errors with ``name``; emit the warnings."""
    double_sided(sides)  # refused whatever the format, so a bad value never passes unnoticed
    if not data:
        raise SceneLoadError(f"{name}: file is empty (0 bytes)")
    try:
        extra = {"sides": sides} if extension in SIDES_OPTION else {}
        objects, warnings = LOADERS[extension](data, extension, name, resolver, limits, **extra)
        limits.check("objects", len(objects), "nodes")
        limits.check("triangles", sum(o.triangle_count for o in objects), "triangles")
        # trimesh's node order is an implementation detail (it reverses OBJ and glTF order); name
        # order is stable across versions and readable.
        objects = sorted(objects, key=lambda obj: obj.name)
        scene = Scene.from_objects(objects, source=name, warnings=warnings)
    except FarfieldError as error:
        # Messages from inside a loader name objects, not the file: name it once, here.
        raise type(error)(f"{name}: {error}") from error
    for message in scene.warnings:
        _warnings.warn(f"{name}: {message}", SceneWarning, stacklevel=3)
    return scene


def load_scene(path: str | Path, limits: SceneLimits = DEFAULT_LIMITS, sides: str = DEFAULT_SIDES) -> Scene:
    """Load the scene file at ``path``; files it refers to are looked up beside it.

    Parameters
    ----------
    path : str or pathlib.Path
        A ``.glb``, ``.gltf``, ``.obj``, ``.ply`` or ``.stl`` file.
    limits : SceneLimits
        The most structure the file may have (:mod:`farfield.core.exchange.limits`).
    sides : str
        ``"one"`` (the default) or ``"both"``: the sidedness of the objects of a format that states
        none (OBJ, PLY, STL); glTF follows its materials' ``doubleSided``.

    Returns
    -------
    Scene
        Objects sorted by name.  ``source`` is the file's name (not its folder).

    Raises
    ------
    SceneNotFoundError
        No file at ``path``.
    SceneLoadError
        Unsupported extension, unreadable or corrupt file, absurd coordinates, a ``sides`` other
        than ``"one"`` or ``"both"``.
    SceneTooCostlyError
        Structure beyond ``limits``.
    DegenerateGeometryError
        No triangles, non-finite coordinates, or zero extent.

    Warns
    -----
    SceneWarning
        For each recoverable problem (also in ``Scene.warnings``).
    """
    path = Path(path)
    if not path.exists():
        raise SceneNotFoundError(f"{path}: no such file")
    if path.is_dir():
        raise SceneLoadError(f"{path}: is a directory, not a scene file")
    extension = _extension(path.suffix, str(path))
    try:
        data = path.read_bytes()
    except OSError as error:
        raise SceneLoadError(f"{path}: cannot read: {error.strerror or error}") from error
    return _load(data, extension, path.name, asset_resolver(path.name, directory=str(path.parent)), limits, sides)


def load_scene_bytes(
    data: bytes,
    extension: str,
    name: str,
    assets: Mapping[str, bytes] | None = None,
    limits: SceneLimits = DEFAULT_LIMITS,
    sides: str = DEFAULT_SIDES,
) -> Scene:
    """Load a scene from the bytes of its file (an upload).

    Parameters
    ----------
    data : bytes
        The scene file's content.
    extension : str
        Its format: ``"glb"``, ``".obj"``, ... (case and leading dot do not matter).
    name : str
        The file's name, used in messages, as ``Scene.source``, and (OBJ) for an unnamed object.
    assets : mapping of str to bytes, or None
        Files the scene refers to (MTL, textures, glTF buffers) by the name it uses for them.
        Without them, such references are reported as missing (a warning for textures).
    limits : SceneLimits
        As :func:`load_scene`.
    sides : str
        As :func:`load_scene`.

    Returns
    -------
    Scene
        Equal to ``load_scene`` of the same file and its referenced files with the same ``sides``
        (same content hash).

    Raises
    ------
    SceneLoadError, DegenerateGeometryError
        As :func:`load_scene`.
    """
    key = _extension(extension, name)
    return _load(bytes(data), key, name, asset_resolver(name, assets=assets), limits, sides)
