"""``farfield glb``: an impostor's GLB with KTX2 textures (Basis Universal, ``KHR_texture_basisu``)
and meshopt geometry (``EXT_meshopt_compression``), for engines and web viewers
(:func:`farfield.core.impostor.glb_compression.compress_glb`).  The plain GLB (PNG pages) stays what bakes and jobs
write; this makes the compressed one from it."""

from __future__ import annotations

import json
import os
import tempfile
import time
from pathlib import Path

import click

from farfield.core.errors import BundleFormatError, NotFoundError
from farfield.core.impostor.bundle import GLB_NAME
from farfield.core.impostor.glb_compression import CODECS, GEOMETRY, TEXTURES, compress_glb


def glb_input(path: Path) -> Path:
    """The GLB of ``path``: the file itself, or a bundle folder's ``impostor.glb``."""
    if path.is_dir():
        path = path / GLB_NAME
    if not path.is_file():
        raise NotFoundError(f"{path}: no such GLB (give an impostor's .glb or its bundle folder)")
    return path


def write_whole(out: Path, data: bytes) -> None:
    """``data`` to ``out`` through a temporary file beside it, renamed into place (readable as a
    plain new file would be); on failure nothing is left and the error is one line."""
    tmp = None
    try:
        if out.is_dir():
            raise IsADirectoryError(21, "is a folder")
        out.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=out.parent, prefix=f".{out.name}.", delete=False) as handle:
            tmp = Path(handle.name)
            handle.write(data)
        umask = os.umask(0)
        os.umask(umask)
        tmp.chmod(0o666 & ~umask)
        os.replace(tmp, out)
    except OSError as error:
        if tmp is not None:
            tmp.unlink(missing_ok=True)
        raise BundleFormatError(f"cannot write {str(out)!r}: {error.strerror or error}") from None


@click.command("glb")
@click.argument("source", type=click.Path(path_type=Path))
@click.option(
    "--out", type=click.Path(path_type=Path), required=True, help="the GLB to write (written whole, or not at all)"
)
@click.option("--textures", type=click.Choice(TEXTURES), default="ktx2", show_default=True,
              help="png: as baked; ktx2: Basis Universal pages, KHR_texture_basisu required; ktx2+png: the PNG kept as fallback")  # fmt: skip
@click.option(
    "--geometry",
    type=click.Choice(GEOMETRY),
    default="meshopt",
    show_default=True,
    help="meshopt: EXT_meshopt_compression (lossless), required",
)
@click.option(
    "--codec",
    type=click.Choice(CODECS),
    default="etc1s",
    show_default=True,
    help="Basis Universal's codec: etc1s (small) or uastc (near-lossless, Zstandard)",
)
@click.option("--json", "as_json", is_flag=True, help="print the figures as JSON")
def glb_cmd(source: Path, out: Path, textures: str, geometry: str, codec: str, as_json: bool) -> None:
    """Write SOURCE (an impostor GLB, or a bundle folder) with compressed textures and geometry."""
    given = click.get_current_context().get_parameter_source("codec") is not click.core.ParameterSource.DEFAULT
    if given and textures == "png":
        raise BundleFormatError(
            f"--codec {codec} encodes KTX2 textures; with --textures png there are none (give --textures ktx2 or ktx2+png)"
        )
    path = glb_input(source)
    plain = path.read_bytes()
    start = time.perf_counter()
    data = compress_glb(plain, textures, geometry, codec)
    seconds = time.perf_counter() - start
    write_whole(out, data)
    figures = {"source": str(path), "out": str(out), "textures": textures, "geometry": geometry, "codec": codec,
               "bytes_before": len(plain), "bytes_after": len(data), "ratio": len(data) / len(plain), "seconds": seconds}  # fmt: skip
    if as_json:
        click.echo(json.dumps(figures, indent=1))
    else:
        click.echo(f"{out}: {len(data):,} bytes ({figures['ratio']:.2f} of {len(plain):,}; textures {textures}"
                   f"{' ' + codec if textures != 'png' else ''}, geometry {geometry}) in {seconds:.2f} s")  # fmt: skip
