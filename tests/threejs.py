"""Independent checks from outside farfield: three.js drawing a scene or bundle file in headless
chromium, (h, w, 4) uint8 images top row first (and where the Khronos glTF validator lies).

Both are npm packages pinned in ``tests/js/package.json`` (``three`` 0.187.0, ``gltf-validator``
2.0.0-dev.3.10), installed into ``tests/js/node_modules`` by ``scripts/install-js`` (``.ci/run``
and ``./run-tests`` call it).  Without them (or without node or chromium) the tests that need
them skip with :data:`THREE_SKIP_REASON` / :data:`VALIDATOR_SKIP_REASON`.

three.js
    :class:`ThreeRenderer` opens one page (``tests/js/render.html``) in the session's chromium
    (``tests/browser.py``'s launch) and keeps it for every render; the page, three.js and the
    files drawn are served to it by Playwright's request routing under :data:`ORIGIN`
    (``/three/`` is ``node_modules/three``, ``/file/<absolute path>`` a file on disk), so no
    server runs.  WebGL 2 there is ANGLE on SwiftShader (Vulkan), chromium's software renderer:
    with ``--disable-gpu`` headless chromium 156 uses it by itself, and
    ``--enable-unsafe-swiftshader`` (in :data:`browser.CHROMIUM_ARGS`) keeps it allowed where
    chromium no longer falls back to it automatically.  What the page draws: see
    ``tests/js/render.mjs`` (glTF's unlit rule with every material, no antialiasing, no tone
    mapping, sRGB output, alpha 255 where drawn, three.js's own colour management).  Two optional
    modes of :meth:`ThreeRenderer.render`: ``lights=`` (with ``ambient=``) draws the file lit, every
    material a ``MeshStandardMaterial`` (glTF's own; others with roughness 1, metalness 0) under
    ``THREE.DirectionalLight`` s and an ``AmbientLight``, as
    :func:`farfield.core.quality.lighting.shade` shades a G-buffer; ``output="normal"`` draws
    world-space shading normals (normal maps applied) as ``n * 0.5 + 0.5`` bytes, not sRGB-encoded.
validator
    see ``tests/glb_validation.py``.
"""

from __future__ import annotations

import base64
import json
import shutil
import urllib.parse
from pathlib import Path

import numpy as np

JS_DIR = Path(__file__).resolve().parent / "js"
DASHBOARD_DIR = Path(__file__).resolve().parents[1] / "api" / "dashboard"
NODE_MODULES = JS_DIR / "node_modules"
THREE_MODULE = NODE_MODULES / "three" / "build" / "three.module.js"
VALIDATOR_MODULE = NODE_MODULES / "gltf-validator" / "index.js"
ORIGIN = "http://farfield.test"  # never resolved: Playwright answers every request under it
THREE_SKIP_REASON = f"needs three.js at {THREE_MODULE} (scripts/install-js installs the pinned npm packages)"
VALIDATOR_SKIP_REASON = f"needs node and the glTF validator at {VALIDATOR_MODULE} (scripts/install-js installs it)"
_KINDS = {".glb": "gltf", ".gltf": "gltf", ".obj": "obj", ".ply": "ply"}
_PAGE_TIMEOUT_MS = 60_000  # SwiftShader compiles three.js's shaders slowly on two cores


def node() -> str | None:
    """The ``node`` executable on PATH, or None."""
    return shutil.which("node")


def three_available() -> bool:
    return THREE_MODULE.is_file()


def validator_available() -> bool:
    return node() is not None and VALIDATOR_MODULE.is_file()


def installed_versions() -> dict[str, str]:
    """``{package: version}`` of the npm packages installed in ``tests/js/node_modules``."""
    versions = {}
    for name in ("three", "gltf-validator"):
        manifest = NODE_MODULES / name / "package.json"
        if manifest.is_file():
            versions[name] = json.loads(manifest.read_text(encoding="utf-8")).get("version", "?")
    return versions


def camera_spec(camera) -> dict:
    """A :class:`farfield.core.render.raster.Camera` as the page takes it (plain lists)."""
    return {
        "eye": [float(x) for x in camera.eye], "right": [float(x) for x in camera.right],
        "up": [float(x) for x in camera.up], "forward": [float(x) for x in camera.forward],
        "fov": float(camera.fov), "near": float(camera.near), "far": float(camera.far),
        "resolution": int(camera.resolution),
    }  # fmt: skip


def lit_spec(lights, ambient=None) -> dict:
    """The page's ``lit`` field: ``lights`` (DirectionalLight-like: ``direction`` toward the light,
    ``colour`` linear RGB, ``intensity``) and ``ambient`` (3,) linear RGB (default
    :data:`farfield.core.quality.lighting.AMBIENT`)."""
    from farfield.core.quality.lighting import AMBIENT

    return {
        "lights": [
            {
                "direction": [float(x) for x in light.direction],
                "color": [float(x) for x in light.colour],
                "intensity": float(light.intensity),
            }
            for light in lights
        ],
        "ambient": [float(x) for x in (AMBIENT if ambient is None else ambient)],
    }


def decode_normals(image: np.ndarray) -> np.ndarray:
    """(h, w, 3) float64 unit normals of an ``output="normal"`` render (h, w, 4) uint8 (0 where
    nothing was drawn)."""
    n = image[..., :3].astype(np.float64) / 255.0 * 2.0 - 1.0
    length = np.linalg.norm(n, axis=-1, keepdims=True)
    return np.where((image[..., 3:] > 0) & (length > 0), n / np.where(length > 0, length, 1.0), 0.0)


def file_url(path: Path) -> str:
    """The page's URL of a file on disk."""
    return f"{ORIGIN}/file{urllib.parse.quote(str(Path(path).resolve()))}"


def _mtl_of(obj: Path) -> Path | None:
    """The first ``mtllib`` an OBJ names, when that file is beside it (farfield reads it too)."""
    with open(obj, encoding="utf-8", errors="replace") as text:
        for line in text:
            if line.startswith("mtllib"):
                candidate = obj.parent / line.split(None, 1)[1].strip()
                return candidate if candidate.is_file() else None
    return None


class ThreeRenderer:
    """One three.js page in ``browser`` (a Playwright browser), drawing files from farfield cameras."""

    def __init__(self, browser):
        from playwright.sync_api import TimeoutError as PlaywrightTimeout

        self.context = browser.new_context(viewport={"width": 256, "height": 256})
        self.page = self.context.new_page()
        self.page.set_default_timeout(_PAGE_TIMEOUT_MS)
        self.errors: list[str] = []
        self.page.on("pageerror", lambda error: self.errors.append(str(error)))
        self.page.route(ORIGIN + "/**", self._serve)
        self.page.goto(ORIGIN + "/js/render.html")
        try:
            self.page.wait_for_function("window.farfieldReady === true")
        except PlaywrightTimeout as error:  # a timeout says nothing without the page's own errors
            raise RuntimeError(f"the three.js page did not start: {self.errors or error}") from error
        self.info = self.page.evaluate("window.farfieldInfo()")

    @staticmethod
    def _serve(route) -> None:
        path = urllib.parse.unquote(urllib.parse.urlsplit(route.request.url).path)
        if path.startswith("/three/"):
            file = NODE_MODULES / "three" / path[len("/three/") :]
        elif path.startswith("/js/"):
            file = JS_DIR / path[len("/js/") :]
        elif path.startswith("/dashboard/"):  # the modules the service ships (octahedral-impostor.js)
            file = DASHBOARD_DIR / path[len("/dashboard/") :]
        elif path.startswith("/file/"):
            file = Path(path[len("/file") :])
        else:
            file = None
        if file is None or not file.is_file():
            route.fulfill(status=404, body=f"not found: {path}")
        else:
            route.fulfill(path=str(file))

    def render(
        self,
        path,
        cameras,
        alpha_cutoff: float | None = None,
        map_replaces_color: bool = False,
        mipmaps: bool = True,
        sides: str | None = None,
        lights=None,
        ambient=None,
        output: str = "colour",
        octahedral: bool = False,
        occluder: dict | None = None,
    ) -> list[np.ndarray]:
        """(h, w, 4) uint8 images of the file at ``path`` (.glb, .gltf, .obj with its MTL, .ply),
        top row first, alpha 255 where drawn, 0 elsewhere; one per camera of ``cameras`` (a
        :class:`farfield.core.render.raster.Camera` or a list of them).

        ``alpha_cutoff`` replaces every material's alpha test (an OBJ's textures with alpha are
        cut at 0.5 by farfield; three.js's MTLLoader cuts nothing); ``map_replaces_color``
        draws a textured material in its texture's colour alone (as Blender's importer does; by
        default ``Kd`` × ``map_Kd``, as the MTL specification, three.js and farfield read it);
        ``mipmaps=False`` samples every texture without
        mipmaps whatever its sampler asks (as farfield's renderer does), to tell the sampler's part
        in a difference.  Sidedness is the source's, as three.js's loaders read it (glTF's
        ``doubleSided``; OBJ and PLY front faces only, their loaders' default and farfield's
        ``sides="one"``); ``sides="both"`` draws every face from both sides (farfield's
        ``sides="both"``).

        ``lights`` (a sequence of :class:`farfield.core.quality.lighting.DirectionalLight`, or of
        objects with the same ``direction``, ``colour``, ``intensity``) draws the file lit: every
        material a ``MeshStandardMaterial`` (a glTF material's own parameters; an OBJ or PLY one
        with roughness 1 and metalness 0, keeping its colour, textures, alpha test and side), one
        ``THREE.DirectionalLight`` per light (placed at ``direction``, aimed at the origin) and an
        ``AmbientLight`` of linear RGB ``ambient`` (3,) (default
        :data:`farfield.core.quality.lighting.AMBIENT`), no environment map, no tone mapping, sRGB
        output.  ``output="normal"`` instead writes each drawn pixel's world-space shading normal
        ``n`` (after the material's normal map; flipped on the back of a double-sided face) as
        ``round((n * 0.5 + 0.5) * 255)``, with no sRGB encoding; :func:`decode_normals` reads it.

        ``octahedral=True`` draws a GLB's ``FARFIELD_octahedral_impostor`` cards with the module
        the service ships (``api/dashboard/octahedral-impostor.js``, served as ``/dashboard/``),
        as an engine would, instead of their fallback card.  ``occluder`` (``centre``, ``normal``,
        ``size``: world) adds an opaque unlit magenta square there, to see where what is drawn
        writes its depth.
        """
        path = Path(path)
        cameras = list(cameras) if isinstance(cameras, (list, tuple)) else [cameras]
        kind = _KINDS.get(path.suffix.lower())
        if kind is None:
            raise ValueError(f"three.js harness: no loader for {path.name}")
        if output not in ("colour", "normal"):
            raise ValueError(f"three.js harness: output must be 'colour' or 'normal', got {output!r}")
        mtl = _mtl_of(path) if kind == "obj" else None
        spec = {
            "kind": kind,
            "url": file_url(path),
            "mtl": file_url(mtl) if mtl else None,
            "alphaCutoff": alpha_cutoff,
            "mapReplacesColor": bool(map_replaces_color),
            "mipmaps": bool(mipmaps),
            "sides": sides,
            "cameras": [camera_spec(c) for c in cameras],
        }
        if lights is not None:
            spec["lit"] = lit_spec(lights, ambient)
        if output == "normal":
            spec["output"] = "normal"
        if octahedral:
            spec["octahedral"] = True
        if occluder is not None:
            spec["occluder"] = {k: [float(x) for x in v] if k != "size" else float(v) for k, v in occluder.items()}
        before = len(self.errors)
        encoded = self.page.evaluate("spec => window.farfieldRender(spec)", spec)
        if len(self.errors) > before:
            raise RuntimeError(f"three.js page errors while drawing {path.name}: {self.errors[before:]}")
        images = []
        for camera, data in zip(cameras, encoded, strict=True):
            n = int(camera.resolution)
            pixels = np.frombuffer(base64.b64decode(data), dtype=np.uint8).reshape(n, n, 4)
            images.append(pixels[::-1].copy())  # WebGL reads bottom row first
        return images

    def close(self) -> None:
        self.context.close()
