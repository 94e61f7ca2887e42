"""Layer recording (issue 29 item 3) before and after, measured side by side in one run.

Usage: ``.venv/bin/python benchmarks/bench_recording.py [--before REV] [--rounds N] [--no-envmap] [--once] [--json]``

Each case is timed in a fresh process with this tree's ``farfield`` and with the ``core/`` of git
revision ``--before`` (from ``git archive``, first on the import path; the benchmark code, scenes,
plans and bound are this tree's), alternating, ``--rounds`` times each; a process warms up once,
then keeps the best of 3 (of 2 for the envmap cell).  The table gives the best of all rounds per
tree, and whether the two trees recorded the same bytes.

- ``dense 512`` and ``dense 1024``: :func:`farfield.core.layering.recording.record_layers` of ``bench_layered.py``'s
  102,400-triangle object (vertex colours and a plain colour) from its speed cell, the plan a
  default bake records; beside it the lower bound of issue 29 item 3, one plain render of the
  object at the plan's texels plus the read-back of every layer (``bench_layered.lower_bound_s``).
- ``helmet 512`` (textured) and ``pine 512`` (alpha-cut foliage): the third-party scenes of
  ``../shared/scenes``, a 0.3-diameter cell 1.6 diameters away.
- ``envmap cell``: ``bake_envmap`` of ``bench_envmap.py``'s middle cell in its million-triangle
  city, 512 x 512 faces, 64 layers, six directions: total and record stage, and a hash of the
  pages and quads.

``--once`` (issue 60 item 1) measures instead, in one process, the draw-once prototype below beside
``record_layers`` and the lower bound: the dense object and a scan-like 327,680-triangle surface
(``tests/scenes.py::dense_mesh(7)``) at 512 and 1024, and the envmap city cell's faces at 512; the
fragments each way of drawing visits; and the prototype's coverage against the reference's.

The renderer (llvmpipe or a GPU) is printed.
"""

from __future__ import annotations

import argparse
import hashlib
import io
import json
import os
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

SHARED_SCENES = ROOT.parent / "shared" / "scenes"
THIRD_PARTY = {"helmet": "damaged_helmet/DamagedHelmet.glb", "pine": "scrub_pine/scrubPine.obj"}


def _best(run, repeats: int = 3) -> tuple[float, object]:
    """Warm up once, then the best of ``repeats`` calls of ``run``: (seconds, its last result)."""
    result = run()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        result = run()
        times.append(time.perf_counter() - start)
    return min(times), result


def _digest(*arrays: np.ndarray) -> str:
    digest = hashlib.sha1()
    for a in arrays:
        digest.update(np.ascontiguousarray(a).tobytes())
    return digest.hexdigest()[:12]


def measure(envmap: bool) -> dict:
    """Every case in this process, with whichever ``farfield`` the import path gives."""
    from bench_layered import bake_plan, cell_before, dense_object, lower_bound_s

    from farfield.core.exchange import load_scene
    from farfield.core.layering.recording import record_layers
    from farfield.core.render.context import renderer_info

    cases = {"renderer": renderer_info().renderer}
    dense = dense_object()
    diameter = float(np.max(dense.bounds[1] - dense.bounds[0]))
    parts = [
        (f"dense {r}", dense, bake_plan(dense, cell_before(dense, 1.6 * diameter, 0.3 * diameter), r))
        for r in (512, 1024)
    ]
    for name, path in THIRD_PARTY.items():
        scene = load_scene(SHARED_SCENES / path)
        d = float(np.max(scene.bounds[1] - scene.bounds[0]))
        parts.append((f"{name} 512", scene, bake_plan(scene, cell_before(scene, 1.6 * d, 0.3 * d), 512)))
    for name, scene, plan in parts:
        seconds, recorded = _best(lambda scene=scene, plan=plan: record_layers(scene, plan))
        cases[name] = {
            "seconds": seconds,
            "layers": int(plan.count),
            "texels": [int(r) for r in plan.texture_resolution],
            "pairs": int(recorded.drawn_triangles.sum()),
            "digest": _digest(recorded.rgba),
        }
        if name.startswith("dense"):
            cases[name]["lower_bound_s"] = lower_bound_s(scene, plan, 3)
    if envmap:
        from bench_envmap import detailed_city, street_grid

        from farfield.core.techniques.envmap.technique import EnvmapOptions, bake_envmap

        city = detailed_city(36, 3)
        cells = street_grid(36)
        middle = cells[len(cells) // 2][1]
        options = EnvmapOptions(
            resolution=512, fov_deg=90.0, layers=64, directions=("+x", "-x", "+y", "-y", "+z", "-z")
        )
        bakes = []
        for _ in range(3):  # the first warms up
            start = time.perf_counter()
            imp = bake_envmap(city, middle, options)
            bakes.append((time.perf_counter() - start, imp))
        seconds, imp = min(bakes[1:], key=lambda pair: pair[0])
        cases["envmap cell"] = {
            "seconds": seconds,
            "record_s": min(b.stats["seconds"]["record"] for _, b in bakes[1:]),
            "layers": int(imp.stats["layers"]),
            "digest": _digest(*imp.pages, imp.payload.corners, imp.payload.uv),
        }
    return cases


def run_tree(revision: str | None, envmap: bool, work: Path) -> dict:
    """:func:`measure` in a fresh process: this tree's ``farfield``, or the ``core/`` of ``revision``."""
    env = dict(os.environ)
    if revision is not None:
        root = work / f"rev-{revision}"
        package = root / "farfield"
        if not package.exists():
            package.mkdir(parents=True)
            archive = subprocess.run(
                ["git", "archive", revision, "core"], check=True, capture_output=True, cwd=ROOT
            ).stdout
            with tarfile.open(fileobj=io.BytesIO(archive)) as tar:
                tar.extractall(package, filter="data")
            (package / "__init__.py").write_text("")
        env["PYTHONPATH"] = os.pathsep.join(p for p in (str(root), env.get("PYTHONPATH", "")) if p)
        env["NUMBA_CACHE_DIR"] = str(root / "numba-cache")
    command = [sys.executable, str(Path(__file__).resolve()), "--measure"] + ([] if envmap else ["--no-envmap"])
    result = subprocess.run(command, capture_output=True, text=True, env=env, cwd=ROOT)
    if result.returncode != 0:
        sys.exit(f"bench_recording: the {revision or 'this tree'} process failed:\n{result.stderr[-3000:]}")
    return json.loads(result.stdout.strip().splitlines()[-1])


# ------------------------------------------------------------------ issue 60 item 1: draw once
# A timing prototype of "draw each triangle once and sort its texels into slabs afterwards" (the
# design the issue proposes), to measure how near it can come to the lower bound on this renderer.
# Every triangle is drawn once as its texel-aligned bounding rectangle (the same rectangle rule as
# recording.py's texel_rectangles); the fragment shader finds the exact range of depths the
# triangle takes inside the closed texel square (grown by slab.frag's EPS), which is exactly the
# set of slabs whose clipped polygon the reference's conservative test keeps the texel for, and for
# each such slab: pass 1 takes the image-atomic minimum of slab.frag's depth key (band, 24-bit
# depth) in an r32ui 2D-array image (one layer per slab), pass 2 writes the colour where its key
# won.  Colour is the vertex colour at the texel centre's barycentrics (clamped), not slab.frag's
# nearest polygon point: coverage is the reference's up to rounding, colours of rim texels are not.
ONCE_VERTEX = """#version 450
uniform vec2 resolution;
in vec3 i_tri0; in vec3 i_tri1; in vec3 i_tri2;  // texel x, texel y, 1 / eye depth
in vec4 i_color0; in vec4 i_color1; in vec4 i_color2;
in float i_first;  // the first slab the triangle's depth range meets
flat out vec3 g_tri[3]; flat out vec4 g_color[3]; flat out int g_first;
void main() {
#ifdef PLAIN  // the triangle itself, rasterised by the GL's own rule (texel centres inside)
    vec2 corner = gl_VertexID == 0 ? i_tri0.xy : gl_VertexID == 1 ? i_tri1.xy : i_tri2.xy;
#else
    bvec2 upper = bvec2((gl_VertexID & 1) != 0, (gl_VertexID & 2) != 0);
    vec2 lo = min(i_tri0.xy, min(i_tri1.xy, i_tri2.xy)), hi = max(i_tri0.xy, max(i_tri1.xy, i_tri2.xy));
    vec2 first = floor(lo);
    first -= vec2(equal(first, lo));
    vec2 corner = mix(clamp(first, vec2(0.0), resolution), clamp(floor(hi) + 1.0, vec2(0.0), resolution), upper);
#endif
    gl_Position = vec4(corner / resolution * 2.0 - 1.0, 0.0, 1.0);
    g_tri[0] = i_tri0; g_tri[1] = i_tri1; g_tri[2] = i_tri2;
    g_color[0] = i_color0; g_color[1] = i_color1; g_color[2] = i_color2;
    g_first = int(i_first);
}
"""

ONCE_FRAGMENT = """#version 450
layout(r32ui, binding = 0) uniform coherent uimage2DArray keys;
layout(rgba8, binding = 1) uniform writeonly image2DArray colours;
uniform bool colour_pass;  // one program for both passes, so that both compute the same keys
uniform sampler2D inverse_borders;  // 1 / border depth, nearest first (so descending)
uniform int group_first;  // the first slab of this group of image layers
uniform int group_count;
flat in vec3 g_tri[3]; flat in vec4 g_color[3]; flat in int g_first;
out vec4 frag_color;
const float EPS = 1e-4;
float cross2(vec2 a, vec2 b) { return a.x * b.y - a.y * b.x; }

void main() {
    frag_color = vec4(0.0);
#ifdef CONSTANT
    return;
#else
    vec2 c = gl_FragCoord.xy;
    vec2 p[3] = vec2[3](g_tri[0].xy, g_tri[1].xy, g_tri[2].xy);
    float area = cross2(p[1] - p[0], p[2] - p[0]);
    if (abs(area) <= 1e-12) { discard; }
    // Barycentrics as in slab.frag (cross products about the point, stable for thin triangles);
    // w (1 / depth) is affine in texel coordinates on the triangle: w(q) = w_0 + grad . (q - p_0).
    vec3 w3 = vec3(g_tri[0].z, g_tri[1].z, g_tri[2].z);
    vec2 grad = (vec2(p[2].y - p[0].y, p[0].x - p[2].x) * (w3.y - w3.x) + vec2(p[0].y - p[1].y, p[1].x - p[0].x) * (w3.z - w3.x)) / area;
    // The range of w over the triangle inside the closed square: its vertices are among the
    // square's corners inside the triangle, the triangle's corners inside the square and the ends
    // of the triangle's edges clipped to the square.
    float h = 0.5 + EPS;
    vec2 lo = c - h, hi = c + h;
    float wmin = 1e30, wmax = -1e30;
    for (int k = 0; k < 4; ++k) {
        vec2 q = c + vec2((k & 1) == 0 ? -h : h, (k & 2) == 0 ? -h : h);
        vec3 bary = vec3(cross2(p[1] - q, p[2] - q), cross2(p[2] - q, p[0] - q), cross2(p[0] - q, p[1] - q)) * sign(area);
        if (all(greaterThanEqual(bary, vec3(0.0)))) {
            float w = w3.x + dot(grad, q - p[0]);
            wmin = min(wmin, w); wmax = max(wmax, w);
        }
    }
    for (int i = 0; i < 3; ++i) {  // Liang-Barsky: edge p[i] -> p[i + 1] inside the square
        vec2 a = p[i], d = p[(i + 1) % 3] - a;
        float t0 = 0.0, t1 = 1.0;
        for (int axis = 0; axis < 2; ++axis) {
            if (d[axis] != 0.0) {
                float ta = (lo[axis] - a[axis]) / d[axis], tb = (hi[axis] - a[axis]) / d[axis];
                t0 = max(t0, min(ta, tb)); t1 = min(t1, max(ta, tb));
            } else if (a[axis] < lo[axis] || a[axis] > hi[axis]) {
                t1 = -1.0;
            }
        }
        if (t0 <= t1) {
            float wa = w3[i] + t0 * (w3[(i + 1) % 3] - w3[i]), wb = w3[i] + t1 * (w3[(i + 1) % 3] - w3[i]);
            wmin = min(wmin, min(wa, wb)); wmax = max(wmax, max(wa, wb));
        }
    }
    if (wmin > wmax) { discard; }  // the square misses the triangle
    vec3 bary = vec3(cross2(p[1] - c, p[2] - c), cross2(p[2] - c, p[0] - c), cross2(p[0] - c, p[1] - c)) / area;
    bool inside = all(greaterThanEqual(bary, vec3(0.0)));
    float wc = w3.x + dot(grad, c - p[0]);
    // Slabs whose closed range [1 / far, 1 / near] of w meets [wmin, wmax], from the triangle's first.
    int i = max(g_first - group_first, 0);
    float near_w = texelFetch(inverse_borders, ivec2(group_first + i, 0), 0).r;
    for (; i < group_count; ++i) {
        float far_w = texelFetch(inverse_borders, ivec2(group_first + i + 1, 0), 0).r;
        if (far_w > wmax) { near_w = far_w; continue; }  // the slab lies in front of the triangle here
        if (near_w < wmin) { break; }  // and every later one behind it
        bool shown = inside && wc <= near_w && wc >= far_w;
        float depth = clamp(1.0 / wc, 1.0 / near_w, 1.0 / far_w);
        float key_depth = 0.5 * (depth - 1.0 / near_w) / (1.0 / far_w - 1.0 / near_w) + (shown ? 0.0 : 0.5);
        uint key = uint(clamp(key_depth, 0.0, 1.0) * 16777215.0 + 0.5);
#ifdef ONE_PASS  // plain load and store: right only where one thread shades a texel's fragments in draw order
        if (key <= imageLoad(keys, ivec3(c, i)).r) {
            imageStore(keys, ivec3(c, i), uvec4(key));
#else
        if (!colour_pass) {
            imageAtomicMin(keys, ivec3(c, i), key);
        } else if (imageLoad(keys, ivec3(c, i)).r == key) {
#endif
            vec3 b = max(bary, vec3(0.0)) * w3;
            b /= b.x + b.y + b.z;
            vec4 colour = b.x * g_color[0] + b.y * g_color[1] + b.z * g_color[2];
            imageStore(colours, ivec3(c, i), vec4(colour.rgb, 1.0));
        }
        near_w = far_w;
    }
#endif
}
"""


def _clip_near(corners: np.ndarray, colours: np.ndarray, near: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Triangles (n, 3, 3) eye corners with (n, 3, 4) colours clipped to z >= ``near`` (a city's
    triangles that cross the eye plane): the pieces, fanned into triangles, and each piece's source row."""
    pieces, paints, rows = [], [], []
    for row in range(corners.shape[0]):
        polygon, paint = [], []
        for j in range(3):
            p, q, cp, cq = corners[row, j], corners[row, (j + 1) % 3], colours[row, j], colours[row, (j + 1) % 3]
            if p[2] >= near:
                polygon.append(p)
                paint.append(cp)
            if (p[2] >= near) != (q[2] >= near):
                t = (near - p[2]) / (q[2] - p[2])
                x = p + t * (q - p)
                x[2] = near
                polygon.append(x)
                paint.append(cp + t * (cq - cp))
        for j in range(1, len(polygon) - 1):
            pieces.append([polygon[0], polygon[j], polygon[j + 1]])
            paints.append([paint[0], paint[j], paint[j + 1]])
            rows.append(row)
    return np.array(pieces).reshape(-1, 3, 3), np.array(paints).reshape(-1, 3, 4), np.array(rows, dtype=np.int64)


def draw_once_records(objects, plan) -> tuple[np.ndarray, int]:
    """(n, 22) float32 per-triangle records of :data:`ONCE_VERTEX` for every triangle of ``objects``
    whose depth range meets the plan's slabs, in draw order (a triangle crossing the first border
    clipped to it, its pieces in its place); and n."""
    from farfield.core.layering.recording import eye_coordinates, texel_coordinates

    borders = plan.borders + plan.reference_offset
    records = []
    for obj in objects:
        corners = eye_coordinates(plan, obj.vertices)[obj.faces]  # (f, 3 corners, 3)
        if obj.vertex_colors is not None:
            colours = obj.vertex_colors[obj.faces] / 255.0
        else:
            colours = np.broadcast_to(np.asarray(obj.base_color, np.float64), obj.faces.shape + (4,))
        z = corners[..., 2]
        keep = (z.max(axis=1) >= borders[0]) & (z.min(axis=1) <= borders[-1])
        crossing = keep & (z.min(axis=1) < borders[0])
        whole = np.flatnonzero(keep & ~crossing)
        pieces, paints, rows = _clip_near(corners[crossing], colours[crossing], borders[0])
        order = np.argsort(np.concatenate([whole, np.flatnonzero(crossing)[rows]]), kind="stable")
        corners = np.concatenate([corners[whole], pieces])[order]
        colours = np.concatenate([colours[whole], paints])[order]
        texel = texel_coordinates(np.moveaxis(corners, 2, 0), plan.frustum_half_tangents, plan.texture_resolution)
        r = np.empty((corners.shape[0], 22), "<f4")
        for j in range(3):
            r[:, 3 * j : 3 * j + 2] = texel[:, :, j].T
            r[:, 3 * j + 2] = 1.0 / corners[:, j, 2]
            r[:, 9 + 4 * j : 13 + 4 * j] = colours[:, j]
        r[:, 21] = np.clip(np.searchsorted(borders[1:], corners[..., 2].min(axis=1)), 0, plan.count - 1)
        records.append(r)
    records = np.ascontiguousarray(np.concatenate(records))
    return records, records.shape[0]


class DrawOnce:
    """The draw-once prototype on the process's GL context: :meth:`record` gives (k, h, w, 4) uint8
    layers (two atomic passes, or one pass of plain loads and stores); :meth:`floor` draws the bare
    rectangles (a constant fragment shader) and reads the layers back, the floor of any scheme that
    visits each triangle's conservative texels once; :meth:`draw_constant` and
    :meth:`exact_fragments` count fragments."""

    GROUP_BYTES = 256 << 20  # image layers per group: keys and colours of at most this many bytes

    def __init__(self, scene, plan) -> None:
        import moderngl

        from farfield.core.render.context import gl_context

        self.moderngl, self.ctx, self.plan = moderngl, gl_context(), plan
        self.res = tuple(int(r) for r in plan.texture_resolution)
        self.k = int(plan.count)
        rx, ry = self.res
        self.group = max(1, min(self.k, self.GROUP_BYTES // (8 * rx * ry)))
        records, self.n = draw_once_records(scene.objects if hasattr(scene, "objects") else scene, plan)
        self.buffer = self.ctx.buffer(records.tobytes())
        # Each group of image layers draws only the triangles whose depth range meets its slabs.
        borders = plan.borders + plan.reference_offset
        first = records[:, 21].astype(np.int64)
        far = 1.0 / records[:, [2, 5, 8]].astype(np.float64).min(axis=1) * (1.0 + 1e-5)  # float32 w: a margin
        last = np.clip(np.searchsorted(borders[:-1], far, side="right") - 1, first, self.k - 1)
        self.groups = []  # (first layer, layers, triangles, buffer)
        for start in range(0, self.k, self.group):
            count = min(self.group, self.k - start)
            meets = (first < start + count) & (last >= start)
            self.groups.append(
                (start, count, int(meets.sum()), self.ctx.buffer(np.ascontiguousarray(records[meets]).tobytes()))
            )
        inverse = (1.0 / (plan.borders + plan.reference_offset)).astype("<f4")
        self.borders = self.ctx.texture((inverse.shape[0], 1), 1, inverse.tobytes(), dtype="f4")
        self.keys = self.ctx.texture_array((rx, ry, self.group), 1, dtype="u4")
        self.colours = self.ctx.texture_array((rx, ry, self.group), 4)
        self.target = self.ctx.renderbuffer((rx, ry), 4)
        self.fbo = self.ctx.framebuffer([self.target])
        self.query = self.ctx.query(samples=True)
        self.programs = {}
        self.arrays = {name: self._array(name) for name in ("CONSTANT", "PASSES", "ONE_PASS")}
        self.arrays["PLAIN"] = self._array("CONSTANT", "PLAIN")
        self.group_arrays = [
            {name: self._array(name, buffer=buffer)[1] for name in ("CONSTANT", "PASSES", "ONE_PASS")}
            for *_, buffer in self.groups
        ]
        self.clear_keys = b"\xff" * (rx * ry * self.group * 4)
        self.clear_colours = bytes(rx * ry * self.group * 4)

    def _array(self, define: str, vertex_define: str = "", buffer=None):
        """(program, vertex array over ``buffer``, default every triangle); one program per variant."""
        key = (define, vertex_define)
        if key in self.programs:
            prog = self.programs[key]
            return prog, self._vertex_array(prog, buffer)
        vertex = (
            ONCE_VERTEX.replace("#version 450", f"#version 450\n#define {vertex_define}", 1)
            if vertex_define
            else ONCE_VERTEX
        )
        prog = self.ctx.program(
            vertex_shader=vertex,
            fragment_shader=ONCE_FRAGMENT.replace("#version 450", f"#version 450\n#define {define}", 1),
        )
        self.programs[key] = prog
        prog["resolution"].value = tuple(float(r) for r in self.res)
        if "inverse_borders" in prog:
            prog["inverse_borders"].value = 5
        return prog, self._vertex_array(prog, buffer)

    def _vertex_array(self, prog, buffer):
        fields = "3f 3f 3f 4f 4f 4f 1f".split()
        names = ("i_tri0", "i_tri1", "i_tri2", "i_color0", "i_color1", "i_color2", "i_first")
        fmt = " ".join(f if name in prog else f"{4 * int(f[:-1])}x" for f, name in zip(fields, names))
        buffer = self.buffer if buffer is None else buffer
        return self.ctx.vertex_array(prog, [(buffer, fmt + " /i", *(n for n in names if n in prog))])

    def _begin(self) -> None:
        self.fbo.use()
        self.ctx.viewport = (0, 0, *self.res)
        self.ctx.disable(self.moderngl.DEPTH_TEST | self.moderngl.CULL_FACE | self.moderngl.BLEND)
        self.borders.use(5)

    def draw_constant(self, plain: bool = False) -> int:
        """Draw every rectangle once with a constant fragment shader (``plain``: every triangle, by
        the GL's rule); the fragments it ran."""
        self._begin()
        with self.query:
            if plain:
                self.arrays["PLAIN"][1].render(self.moderngl.TRIANGLES, vertices=3, instances=self.n)
            else:
                self.arrays["CONSTANT"][1].render(self.moderngl.TRIANGLE_STRIP, vertices=4, instances=self.n)
        self.ctx.finish()
        return int(self.query.samples)

    def floor(self) -> None:
        """One conservative draw with a constant fragment shader per group of layers, and the
        read-back of every layer: what any draw-once scheme pays before it decides a texel."""
        self._begin()
        for (*_, n, _), arrays in zip(self.groups, self.group_arrays):
            arrays["CONSTANT"].render(self.moderngl.TRIANGLE_STRIP, vertices=4, instances=n)
            self.colours.read()

    def exact_fragments(self) -> int:
        """The fragments the prototype's coverage test keeps (texel squares meeting a triangle,
        whatever their slabs): one key pass over every triangle with no image layer to write."""
        self._begin()
        prog, array = self.arrays["PASSES"]
        prog["group_first"].value, prog["group_count"].value, prog["colour_pass"].value = 0, 0, False
        with self.query:
            array.render(self.moderngl.TRIANGLE_STRIP, vertices=4, instances=self.n)
        self.ctx.finish()
        return int(self.query.samples)

    def record(self, one_pass: bool = False) -> np.ndarray:
        """The layers, (k, h, w, 4) uint8; ``one_pass``: keys and colours in one pass of plain image
        loads and stores, which is right only where one thread shades each texel's fragments in draw
        order (llvmpipe's tiles, it seems; never a GPU's)."""
        rx, ry = self.res
        out = np.empty((self.k, ry, rx, 4), np.uint8)
        self._begin()
        name = "ONE_PASS" if one_pass else "PASSES"
        prog = self.arrays[name][0]
        for (first, count, n, _), arrays in zip(self.groups, self.group_arrays):
            self.keys.write(self.clear_keys)
            self.colours.write(self.clear_colours)
            self.keys.bind_to_image(0, read=True, write=True)
            self.colours.bind_to_image(1, read=False, write=True)
            prog["group_first"].value, prog["group_count"].value = first, count
            for colour_pass in (False,) if one_pass else (False, True):
                if "colour_pass" in prog:
                    prog["colour_pass"].value = colour_pass
                arrays[name].render(self.moderngl.TRIANGLE_STRIP, vertices=4, instances=n)
                self.ctx.memory_barrier()
            out[first : first + count] = np.frombuffer(self.colours.read(), np.uint8).reshape(self.group, ry, rx, 4)[
                :count
            ]
        return out

    def release(self) -> None:
        from farfield.core.render.programs import park_framebuffer

        self.ctx.finish()
        park_framebuffer(self.ctx)  # never release the bound framebuffer (core/render/programs.py)
        for resource in (*(a for _, a in self.arrays.values()), *self.programs.values(), self.buffer,
                         *(a for arrays in self.group_arrays for a in arrays.values()), *(g[3] for g in self.groups),
                         self.borders, self.keys, self.colours, self.fbo, self.target):  # fmt: skip
            resource.release()


def face_bound_s(objects, face) -> float:
    """The lower bound of one cube face of an envmap cell: one plain render of ``objects`` from the
    face's viewpoint along its axis (90 degrees, its texels), plus the read-back of its layers."""
    from farfield.core.render.context import gl_context
    from farfield.core.render.programs import park_framebuffer
    from farfield.core.render.raster import Camera, MeshRenderer

    res = int(face.texture_resolution[0])
    ctx = gl_context()
    eye = np.asarray(face.reference_viewpoint, np.float64)
    with MeshRenderer(objects) as renderer:
        camera = Camera.look_at(eye, eye + face.axis, np.pi / 2, res, 0.5 * face.borders[0], 2.0 * face.borders[-1])
        renderer.render(camera)
        texture = ctx.texture((res, res), 4)
        fbo = ctx.framebuffer([texture])
        start = time.perf_counter()
        renderer.render(camera)
        fbo.use()
        for _ in range(face.count):
            texture.read()
        seconds = time.perf_counter() - start
        park_framebuffer(ctx)
        fbo.release()
        texture.release()
    return seconds


def once_cases() -> dict:
    """name -> [(objects, plan, bound)]: the parts each case records, and the function that times
    its lower bound once."""
    from bench_envmap import detailed_city, street_grid
    from bench_layered import bake_plan, cell_before, dense_object, lower_bound_s

    sys.path.insert(0, str(ROOT / "tests"))
    from scenes import dense_mesh

    from farfield.core.sidedness import seen_from_cell
    from farfield.core.techniques.envmap.technique import EnvmapOptions, face_plan, plan_envmap

    cases = {}
    for label, scene in (("dense", dense_object()), ("scan-like", dense_mesh(7))):
        diameter = float(np.max(scene.bounds[1] - scene.bounds[0]))
        cell = cell_before(scene, 1.6 * diameter, 0.3 * diameter)
        for resolution in (512, 1024):
            plan = bake_plan(scene, cell, resolution)
            cases[f"{label} {resolution}"] = [
                (scene.objects, plan, lambda scene=scene, plan=plan: lower_bound_s(scene, plan, 1))
            ]
    city = detailed_city(36, 3)
    cells = street_grid(36)
    middle = cells[len(cells) // 2][1]
    directions = ("+x", "-x", "+y", "-y", "+z", "-z")
    options = EnvmapOptions(resolution=512, fov_deg=90.0, layers=64, directions=directions)
    plan = plan_envmap(middle, options)
    seen = seen_from_cell(city.objects, middle)
    faces = [f for f in (face_plan(name, plan, middle.center, city.bounds) for name in directions) if f is not None]
    cases["city cell 512"] = [(seen, f, lambda f=f: face_bound_s(seen, f)) for f in faces]
    return cases


def measure_once(rounds: int, only: tuple[str, ...] = ()) -> dict:
    """The draw-once prototype beside the reference recording and the lower bound, in this process:
    per part of a case, the best of ``rounds`` interleaved runs (after a warm-up) of the bound,
    ``record_layers``, the draw-once floor and the draw-once prototype, summed over the case's parts;
    the texels each way of drawing visits (fragments: counts, not timing) and the prototype's
    coverage against the reference's."""
    from farfield.core.layering.recording import eye_coordinates, faces_with_area, record_layers, slab_instances
    from farfield.core.render.context import renderer_info

    report = {"renderer": renderer_info().renderer, "rounds": rounds}
    for name, parts in once_cases().items():
        if only and not any(word in name for word in only):
            continue
        print(f"draw once: {name} ...", file=sys.stderr, flush=True)
        case = dict.fromkeys(
            ("reference_fragments", "once_fragments", "plain_fragments", "conservative_fragments", "covered", "missed", "extra", "bound_s",
             "reference_s", "floor_s", "once_s", "one_pass_s", "layers"), 0)  # fmt: skip
        case["triangles"] = int(sum(len(o.faces) for o in parts[0][0]))
        case["texels"] = [int(r) for r in parts[0][1].texture_resolution]
        for objects, plan, bound in parts:
            once = DrawOnce(objects, plan)
            borders = plan.borders + plan.reference_offset
            for obj in objects:
                pairs = slab_instances(eye_coordinates(plan, obj.vertices), obj.faces, borders,
                                       plan.frustum_half_tangents, plan.texture_resolution, faces_with_area(obj))  # fmt: skip
                case["reference_fragments"] += int(np.prod(pairs.rect[2:] - pairs.rect[:2], axis=0).sum())
            runs = {
                "bound": bound,
                "reference": lambda objects=objects, plan=plan: record_layers(objects, plan),
                "floor": once.floor,
                "once": once.record,
                "one_pass": lambda once=once: once.record(one_pass=True),
            }
            times = {run: [] for run in runs}
            results = {run: call() for run, call in runs.items()}  # warm-up
            for _ in range(rounds):
                for run, call in runs.items():
                    start = time.perf_counter()
                    result = call()
                    times[run].append(result if run == "bound" else time.perf_counter() - start)
                    results[run] = result
            reference, recorded = results["reference"].coverage, results["once"][..., 3] > 0
            case["one_pass_same"] = bool(
                case.get("one_pass_same", True) and np.array_equal(results["once"], results["one_pass"])
            )
            case["layers"] += once.k
            case["once_fragments"] += once.draw_constant()
            case["plain_fragments"] += once.draw_constant(plain=True)
            case["conservative_fragments"] += once.exact_fragments()
            case["covered"] += int(reference.sum())
            case["missed"] += int((reference & ~recorded).sum())
            case["extra"] += int((recorded & ~reference).sum())
            for run, t in times.items():
                case[f"{run}_s"] += min(t)
            once.release()
        report[name] = case
    return report


def print_once(report: dict) -> None:
    print(f"renderer: {report['renderer']}   best of {report['rounds']} interleaved runs per part, in one process")
    print("fragments (thousands): plain = the GL's own rule; exact = texel squares meeting a triangle;")
    print("once = the draw-once rectangles; reference = the (triangle, slab) rectangles of record_layers")
    print(
        f"{'case':<15} {'tris':>7} {'layers':>6} {'texels':>9} {'plain':>6} {'exact':>6} {'once':>6} {'refer.':>6} "
        f"{'bound s':>7} {'ref s':>6} {'floor s':>7} {'once s':>6} {'1-pass s':>8} {'ref/b':>6} {'floor/b':>7} {'once/b':>6} {'1-pass/b':>8} {'missed':>6} {'extra':>5}"
    )
    for name, case in report.items():
        if not isinstance(case, dict):
            continue
        b = case["bound_s"]
        frags = (
            case[f] // 1000
            for f in ("plain_fragments", "conservative_fragments", "once_fragments", "reference_fragments")
        )
        print(
            f"{name:<15} {case['triangles']:>7} {case['layers']:>6} {'x'.join(map(str, case['texels'])):>9} "
            + " ".join(f"{f:>6}" for f in frags)
            + f" {b:>7.3f} {case['reference_s']:>6.3f} {case['floor_s']:>7.3f} {case['once_s']:>6.3f} {case.get('one_pass_s', 0):>8.3f}"
            f" {case['reference_s'] / b:>5.1f}x {case['floor_s'] / b:>6.1f}x {case['once_s'] / b:>5.1f}x {case.get('one_pass_s', 0) / b:>7.1f}x"
            f" {case['missed']:>6} {case['extra']:>5}"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--before",
        default="db81940",
        help="git revision recorded beside this tree (default: db81940, before the slab.frag variants)",
    )
    parser.add_argument("--rounds", type=int, default=2, help="fresh processes per tree, alternating (default 2)")
    parser.add_argument(
        "--no-envmap", action="store_true", help="leave out the envmap cell (its city takes a while to build)"
    )
    parser.add_argument(
        "--once",
        action="store_true",
        help="instead: the draw-once prototype (issue 60 item 1) beside the reference and the bound",
    )
    parser.add_argument(
        "--cases", nargs="*", default=[], help="with --once: only the cases whose name has one of these words"
    )
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--measure", action="store_true", help=argparse.SUPPRESS)  # internal: one tree, JSON out
    args = parser.parse_args()
    if args.once:
        report = measure_once(max(args.rounds, 1) + 1, tuple(args.cases))
        if args.json:
            print(json.dumps(report, indent=1))
        else:
            print_once(report)
        return
    if args.measure:
        print(json.dumps(measure(not args.no_envmap)))
        return
    runs: dict[str, list[dict]] = {"before": [], "after": []}
    with tempfile.TemporaryDirectory() as work:
        for r in range(args.rounds):
            for tree, revision in (("before", args.before), ("after", None)):
                print(f"round {r + 1}/{args.rounds}: {tree} ...", file=sys.stderr, flush=True)
                runs[tree].append(run_tree(revision, not args.no_envmap, Path(work)))
    best = {
        tree: {
            name: min((run[name] for run in results), key=lambda case: case["seconds"])
            for name in results[0]
            if name != "renderer"
        }
        for tree, results in runs.items()
    }
    report = {"renderer": runs["after"][0]["renderer"], "before": args.before, "rounds": args.rounds, **best}
    if args.json:
        print(json.dumps(report, indent=1))
        return
    print(
        f"renderer: {report['renderer']}   before: {args.before}   best of {args.rounds} processes x 3 per tree (envmap: x 2)"
    )
    print(
        f"{'case':<12} {'layers':>6} {'texels':>10} {'pairs':>8} {'before s':>9} {'after s':>8} {'speed-up':>8} {'same bytes':>10} {'bound s':>8} {'before/bound':>12} {'after/bound':>11}"
    )
    for name, after in best["after"].items():
        before = best["before"][name]
        texels = "x".join(str(t) for t in after["texels"]) if "texels" in after else ""
        row = f"{name:<12} {after['layers']:>6} {texels:>10} {after.get('pairs', ''):>8} {before['seconds']:>9.3f} {after['seconds']:>8.3f} {before['seconds'] / after['seconds']:>7.2f}x {str(before['digest'] == after['digest']):>10}"
        if "lower_bound_s" in after:
            bound = min(before["lower_bound_s"], after["lower_bound_s"])
            row += f" {bound:>8.3f} {before['seconds'] / bound:>11.1f}x {after['seconds'] / bound:>10.1f}x"
        print(row)
        if "record_s" in after:
            print(
                f"{'':<12} record stage: before {before['record_s']:.3f} s, after {after['record_s']:.3f} s ({before['record_s'] / after['record_s']:.2f}x)"
            )


if __name__ == "__main__":
    main()
