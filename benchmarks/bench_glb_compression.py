"""Bytes of an impostor GLB with KTX2 textures and meshopt geometry, per technique, side by side in
one run (issue 30, item 3), and what the codecs cost in image error and encoding time.

Usage: ``.venv/bin/python benchmarks/bench_glb_compression.py [--resolution 512] [--json OUT]``

One impostor per technique, baked here: the part techniques (layered, tdm, points, ldi) of the
demo house (``farfield scenes demo house``) from the README's cell, ``envmap`` of a 100-building
demo city from a 10-unit cell at (170, 5, 170); and layered impostors of two textured scenes of
``../shared/scenes`` (the damaged helmet's photographic PBR atlas, the scrub pine's alpha-cut leaf
cards), from a cell one diameter in front (the flat-coloured procedural pages are what PNG
compresses best; photographs are what Basis Universal is for).  Each GLB is written plain (PNG pages, plain
buffers: the default) and through :func:`farfield.core.impostor.glb_compression.compress_glb`: meshopt geometry,
KTX2 pages (ETC1S, UASTC), both, and KTX2 with the PNG kept as fallback.  Columns: bytes, and the
ratio to plain; for each codec the decoded pages against the PNG (Basis Universal's own
transcoder to RGBA8): mean absolute RGB error on the texels the alpha cut keeps (0..255), texels
whose side of the 0.5 alpha cut flips, and seconds to encode; GPU bytes of the pages (RGBA8: 4 per
texel; transcoded to BC7/ASTC 4x4/ETC2 RGBA: 1 per texel).
"""

from __future__ import annotations

import argparse
import io
import json
import sys
import time
from pathlib import Path

import numpy as np
from PIL import Image

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT.parent))

from farfield.core.exchange import load_scene  # noqa: E402
from farfield.core.impostor.glb import impostor_glb  # noqa: E402
from farfield.core.impostor.glb_compression import compress_glb, decode_ktx2, read_glb  # noqa: E402
from farfield.core.procedural import demo_scene  # noqa: E402
from farfield.core.techniques import get_technique  # noqa: E402
from farfield.core.viewcells import BoxCell  # noqa: E402

PART_CELL = BoxCell([-40.0, -41.75, -192.0], [60.0, 58.25, -92.0])  # the README's house cell
SCENE_CELL = BoxCell.from_center([170.0, 5.0, 170.0], 10.0)
SHARED = ROOT.parent / "shared" / "scenes"
TEXTURED = {
    "layered (helmet)": SHARED / "damaged_helmet" / "DamagedHelmet.glb",
    "layered (pine)": SHARED / "scrub_pine" / "scrubPine.obj",
}


def cell_in_front(scene) -> BoxCell:
    """A cubic cell a tenth of the part's diameter across, one diameter before it along -x."""
    lo, hi = scene.bounds
    diameter = float(np.max(hi - lo))
    centre = 0.5 * (lo + hi)
    centre[0] = lo[0] - diameter - 0.05 * diameter
    return BoxCell.from_center(centre, 0.1 * diameter)


def pages_of(glb: bytes) -> list[tuple[str, bytes]]:
    document, blob = read_glb(glb)
    out = []
    for image in document.get("images", []):
        view = document["bufferViews"][image["bufferView"]]
        start = view.get("byteOffset", 0)
        out.append((image["mimeType"], blob[start : start + view["byteLength"]]))
    return out


def codec_error(plain: bytes, compressed: bytes) -> tuple[float, int, int]:
    """(mean |RGB| error on kept texels, texels whose alpha cut flips, texels) of the KTX2 pages."""
    pngs = [
        np.asarray(Image.open(io.BytesIO(data)).convert("RGBA"))
        for kind, data in pages_of(plain)
        if kind == "image/png"
    ]
    ktx = [decode_ktx2(data) for kind, data in pages_of(compressed) if kind == "image/ktx2"]
    errors, flips, texels = [], 0, 0
    for a, b in zip(pngs, ktx):
        b = b[: a.shape[0], : a.shape[1]]  # a page grown to whole 4 x 4 blocks: its own texels
        kept = a[..., 3] >= 128
        errors.append(np.abs(a[..., :3].astype(np.int16) - b[..., :3].astype(np.int16))[kept].ravel())
        flips += int((kept != (b[..., 3] >= 128)).sum())
        texels += a.shape[0] * a.shape[1]
    merged = np.concatenate(errors) if errors else np.zeros(0)
    return (float(merged.mean()) if merged.size else 0.0), flips, texels


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--resolution", type=int, default=512)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    house, city = demo_scene("house"), demo_scene("city", 100)
    rows = []
    cases = [
        (name, name, (city, SCENE_CELL) if get_technique(name).scope == "scene" else (house, PART_CELL))
        for name in ("layered", "tdm", "points", "ldi", "envmap")
    ]
    for label, path in TEXTURED.items():
        if path.is_file():
            scene = load_scene(path)
            cases.append((label, "layered", (scene, cell_in_front(scene))))
    for name, technique_name, (scene, cell) in cases:
        technique = get_technique(technique_name)
        impostor = technique.bake(scene, cell, technique.options({}, args.resolution), None, None)
        plain = impostor_glb(impostor)
        row = {
            "technique": name,
            "plain": len(plain),
            "pages": len(impostor.pages),
            "texels": int(sum(p.shape[0] * p.shape[1] for p in impostor.pages)),
        }
        row["geometry_plain"] = len(plain) - sum(len(d) for _, d in pages_of(plain))
        for label, textures, geometry, codec in (("meshopt", "png", "meshopt", "etc1s"), ("etc1s", "ktx2", "plain", "etc1s"), ("uastc", "ktx2", "plain", "uastc"),
                                                 ("etc1s+meshopt", "ktx2", "meshopt", "etc1s"), ("uastc+meshopt", "ktx2", "meshopt", "uastc"), ("etc1s+png", "ktx2+png", "plain", "etc1s")):  # fmt: skip
            start = time.perf_counter()
            data = compress_glb(plain, textures, geometry, codec)
            row[label] = len(data)
            row[f"{label}_seconds"] = time.perf_counter() - start
            if label in ("etc1s", "uastc"):
                row[f"{label}_error"], row[f"{label}_flips"], _ = codec_error(plain, data)
        rows.append(row)
        print(f"{name}: baked and compressed", file=sys.stderr)

    print(f"\nimpostor GLBs at {args.resolution} px, bytes (ratio to plain)\n")
    labels = ("meshopt", "etc1s", "uastc", "etc1s+meshopt", "uastc+meshopt", "etc1s+png")
    print("| technique | pages (texels) | plain (geometry) | " + " | ".join(labels) + " |")
    print("|---|---|---|" + "---|" * len(labels))
    for r in rows:
        cells = [f"{r[k]:,} ({r[k] / r['plain']:.2f})" for k in labels]
        print(
            f"| {r['technique']} | {r['pages']} ({r['texels']:,}) | {r['plain']:,} ({r['geometry_plain']:,}) | "
            + " | ".join(cells)
            + " |"
        )
    print(
        "\ncodec figures: mean |RGB| error on kept texels (0..255), alpha-cut flips, encode seconds; GPU bytes RGBA8 -> 8 bpp"
    )
    print(
        "| technique | etc1s error | etc1s flips | etc1s s | uastc error | uastc flips | uastc s | GPU bytes RGBA8 | transcoded |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['technique']} | {r['etc1s_error']:.2f} | {r['etc1s_flips']:,} | {r['etc1s_seconds']:.2f} | {r['uastc_error']:.2f} | {r['uastc_flips']:,} | {r['uastc_seconds']:.2f} | {4 * r['texels']:,} | {r['texels']:,} |"
        )
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
