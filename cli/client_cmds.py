"""``farfield submit``, ``farfield jobs`` and ``farfield scenes``: the service's client for pipelines and scripts.

The service is found at ``--url`` (``FARFIELD_URL``, default http://127.0.0.1:8000) with the key
``--key`` (``FARFIELD_API_KEY``, else the admin key ``farfield up`` keeps in
``$FARFIELD_HOME/admin.key``).  HTTP errors become one line and the exit code of their kind.
"""

from __future__ import annotations

import io
import json
import math
import os
import time
import zipfile
from pathlib import Path

import click
from tqdm import tqdm

from farfield.cli import object_names, sides_option
from farfield.core.errors import ErrorKind, FarfieldError
from farfield.core.sidedness import DEFAULT_SIDES
from farfield.core.viewcells import parse_viewcell
from farfield.service.placement import ALGORITHMS
from farfield.service.settings import Settings

STATUS_KINDS = {
    401: ErrorKind.UNAUTHORIZED,
    404: ErrorKind.MISSING,
    409: ErrorKind.CONFLICT,
    413: ErrorKind.TOO_LARGE,
    429: ErrorKind.OVER_QUOTA,
    503: ErrorKind.RENDERER_UNAVAILABLE,
}


class ServiceError(FarfieldError):
    """The service refused a request or could not be reached."""

    def __init__(self, message: str, kind: ErrorKind = ErrorKind.BAD_INPUT) -> None:
        super().__init__(message)
        self.kind = kind


class JobEndedBadly(FarfieldError):
    """The submitted job ended failed or cancelled."""

    kind = ErrorKind.CONFLICT


def _default_key() -> str | None:
    if os.environ.get("FARFIELD_API_KEY"):
        return os.environ["FARFIELD_API_KEY"]
    path = Settings.from_env().home / "admin.key"
    return path.read_text().strip() if path.exists() else None


class Client:
    """A thin HTTP client that turns error responses into :class:`ServiceError`."""

    def __init__(self, url: str, key: str | None) -> None:
        import httpx

        self.url = url.rstrip("/")
        if self.url.endswith("/v1"):  # the API URL `farfield up` prints: the routes already start with /v1
            self.url = self.url[: -len("/v1")]
        self.http = httpx.Client(
            base_url=self.url, headers={"Authorization": f"Bearer {key}"} if key else {}, timeout=300
        )

    def request(self, method: str, path: str, **kwargs):
        import httpx

        where = non_finite(kwargs.get("json"))
        if where is not None:  # JSON has no NaN or infinity: say which value, before httpx fails to encode it
            raise ServiceError(f"{where[0] or 'the request'} is {where[1]!r}: the service takes finite numbers only")
        try:
            response = self.http.request(method, path, **kwargs)
        except httpx.TransportError as error:
            raise ServiceError(
                f"cannot reach the service at {self.url}: {error}", ErrorKind.RENDERER_UNAVAILABLE
            ) from None
        if response.status_code >= 400:
            try:
                detail = response.json().get("detail")
            except ValueError:
                detail = response.text
            if isinstance(detail, list):  # FastAPI's validation errors
                detail = "; ".join(
                    f"{'.'.join(str(p) for p in d.get('loc', [])[1:])}: {d.get('msg')}"
                    + (f", got {d['input']!r}" if isinstance(d.get("input"), (str, int, float)) else "")
                    for d in detail
                )  # fmt: skip
            default = (
                ErrorKind.INTERNAL if response.status_code >= 500 else ErrorKind.BAD_INPUT
            )  # a 5xx is the service's fault, never bad input
            raise ServiceError(
                f"{detail} (HTTP {response.status_code})", STATUS_KINDS.get(response.status_code, default)
            )
        return response

    def pages(self, path: str, params: dict | None = None, limit: int = 100, offset: int = 0, every: bool = False):
        """The entries of a paged listing from ``offset``, ``limit`` a page: one page, or ``every``
        page (following the ``Link: rel="next"`` headers); and the ``X-Total-Count``."""
        response = self.request("GET", path, params={**(params or {}), "limit": limit, "offset": offset})
        entries = response.json()
        while every and "next" in response.links:
            response = self.request("GET", response.links["next"]["url"])
            entries += response.json()
        return entries, int(response.headers.get("X-Total-Count", len(entries)))


def non_finite(value, where: str = "") -> tuple[str, float] | None:
    """The first number in a JSON-like ``value`` that is NaN or infinite: (its path, it), or None.

    >>> non_finite({"placement": {"budget": {"frame_ms": float("nan")}}})
    ('placement.budget.frame_ms', nan)
    >>> non_finite({"grid": {"lo": [0.0, float("inf"), 0.0]}}), non_finite({"a": [1, 2.5, "x"]})
    (('grid.lo[1]', inf), None)
    """
    if isinstance(value, float):
        return None if math.isfinite(value) else (where, value)
    items = value.items() if isinstance(value, dict) else enumerate(value) if isinstance(value, (list, tuple)) else ()
    for key, item in items:
        found = non_finite(item, f"{where}[{key}]" if isinstance(key, int) else f"{where}.{key}" if where else str(key))
        if found is not None:
            return found
    return None


def _more(shown: int, offset: int, total: int, what: str) -> None:
    """A note on stderr when a listing shows only part of what there is."""
    if offset + shown < total:
        click.echo(
            f"{what} {offset + 1}-{offset + shown} of {total}: --offset {offset + shown} for the next, --all for every one",
            err=True,
        )


def _listing(
    client: Client, path: str, params: dict | None, paging: tuple[int, int, bool], what: str, as_json: bool, line
) -> None:
    """Print a paged listing: JSON, or ``line(entry)`` per entry, with :func:`_more`'s note."""
    limit, offset, every = paging
    rows, total = client.pages(path, params, limit, offset, every)
    _more(len(rows), offset, total, what)
    if as_json:
        click.echo(json.dumps(rows))
        return
    for row in rows:
        click.echo(line(row))


def _paging_options(f):
    f = click.option("--all", "every", is_flag=True, help="Every page, not one.")(f)
    f = click.option(
        "--offset", type=click.IntRange(0), default=0, show_default=True, help="Entries to skip (newest first)."
    )(f)
    return click.option(
        "--limit", type=click.IntRange(1, 1000), default=100, show_default=True, help="Entries per page."
    )(f)


def _client_options(f):
    f = click.option(
        "--key", default=None, help="API key (FARFIELD_API_KEY; default: the admin key of a local farfield up)."
    )(f)
    return click.option(
        "--url",
        envvar="FARFIELD_URL",
        default="http://127.0.0.1:8000",
        show_default=True,
        help="The service (FARFIELD_URL).",
    )(f)


def parse_grid(text: str) -> dict:
    """``x0,y0,z0,x1,y1,z1,nx,ny,nz`` -> the API's grid.

    >>> parse_grid("0,0,0,2,1,2,2,1,2")
    {'lo': [0.0, 0.0, 0.0], 'hi': [2.0, 1.0, 2.0], 'counts': [2, 1, 2]}
    """
    parts = text.replace(" ", "").split(",")
    try:
        if len(parts) != 9:
            raise ValueError
        numbers = [float(p) for p in parts[:6]]
        counts = [int(p) for p in parts[6:]]
    except ValueError:
        raise ServiceError(f"--grid {text!r}: expected x0,y0,z0,x1,y1,z1,nx,ny,nz") from None
    return {"lo": numbers[:3], "hi": numbers[3:], "counts": counts}


def placement_request(view_space: str, frame_ms, cost_model, primitives, cpv_size, vdi_deg, cells, depth_complexity, leaf_size, max_impostor_mb=None,
                      algorithm=None, **image_knobs) -> dict:  # fmt: skip
    """The ``placement`` of a job request from ``farfield submit --placement``'s flags (those of
    ``farfield place``); --cost-model is a name the service knows (llvmpipe) or a model JSON file.

    >>> placement_request("0,0,0,4,1,4", None, None, 5000, None, None, None, None, None)
    {'view_space': {'lo': [0.0, 0.0, 0.0], 'hi': [4.0, 1.0, 4.0]}, 'budget': {'primitives': 5000}}
    >>> placement_request("0,0,0,4,1,4", None, None, 5000, None, None, None, None, None, algorithm="primitive-budget", p_opt=4000, max_level=None)
    {'view_space': {'lo': [0.0, 0.0, 0.0], 'hi': [4.0, 1.0, 4.0]}, 'budget': {'primitives': 5000}, 'algorithm': 'primitive-budget', 'p_opt': 4000}
    """
    try:
        corners = [float(v) for v in view_space.split(",")]
    except (AttributeError, ValueError):
        corners = []
    if len(corners) != 6:
        raise ServiceError(f"--view-space {view_space!r}: expected x0,y0,z0,x1,y1,z1")
    budget: dict = {"frame_ms": frame_ms, "primitives": primitives}
    if cost_model is not None:
        if Path(cost_model).is_file():
            try:
                budget["cost_model"] = json.loads(Path(cost_model).read_text())
            except (OSError, ValueError) as error:
                raise ServiceError(f"--cost-model {cost_model!r}: not a cost model JSON file ({error})") from None
        else:
            budget["cost_model"] = cost_model
    knobs = {
        "cpv_size": cpv_size,
        "vdi_deg": vdi_deg,
        "cells": cells,
        "depth_complexity": depth_complexity,
        "leaf_size": leaf_size,
        "max_impostor_mb": max_impostor_mb,
        "algorithm": algorithm,
        **image_knobs,
    }
    return {
        "view_space": {"lo": corners[:3], "hi": corners[3:]}, "budget": {k: v for k, v in budget.items() if v is not None},
        **{k: v for k, v in knobs.items() if v is not None},
    }  # fmt: skip


def upload_scene(client: Client, path: Path, sides: str = DEFAULT_SIDES) -> str:
    """Upload the scene file at ``path``; a ``.gltf`` or ``.obj`` that refers to files beside it (buffers,
    images; MTL, textures) goes as a zip of them all (:func:`farfield.core.exchange.archive.pack_scene`).
    ``sides`` is the loader's option (the form field ``sides``, :mod:`farfield.core.sidedness`).
    Returns the scene's id; the loader's warnings (a missing texture) are printed to stderr."""
    from farfield.core.exchange.archive import pack_scene

    packed = pack_scene(path)
    form = {"sides": sides}
    if packed is not None:
        made = client.request(
            "POST", "/v1/scenes", files={"file": (f"{path.stem}.zip", packed, "application/zip")}, data=form
        ).json()
    else:
        with open(path, "rb") as f:
            made = client.request("POST", "/v1/scenes", files={"file": (path.name, f)}, data=form).json()
    for warning in made.get("warnings", []):
        click.echo(f"warning: {warning}", err=True)
    return made["id"]


def placement_line(job: dict) -> str | None:
    """A placement job's planning progress, one line (None for other jobs).

    >>> print(placement_line({"state": "placing", "placement": {"phase": "plan", "step": "candidates", "done": 3, "total": 8, "round": 0}}))
    placement: plan, candidates 3/8, round 0
    """
    record = job.get("placement")
    if not record:
        return None
    line = f"placement: {record.get('phase')}, {record.get('step')}"
    if record.get("total"):
        line += f" {record.get('done', 0)}/{record['total']}"
    line += f", round {record.get('round', 0)}"
    if record.get("impostors") is not None:
        line += f", {record['impostors']} impostors"
    return line


def chosen_line(job: dict) -> str | None:
    """What a placement of mixed candidates chose of each technique (its summary's ``by_technique``:
    layered, octahedral, lod...), one line; None for any other job.

    >>> print(chosen_line({"placement": {"summary": {"by_technique": {
    ...     "layered": {"impostors": 2, "memory_bytes": 3 * 2**20, "cpvs": 5},
    ...     "lod": {"impostors": 4, "memory_bytes": 2**19, "cpvs": 9}}}}}))
    chosen: layered 2 (3.00 MiB, drawn in 5 CPVs); lod 4 (0.50 MiB, drawn in 9 CPVs)
    """
    rows = ((job.get("placement") or {}).get("summary") or {}).get("by_technique")
    if not rows:
        return None
    return "chosen: " + "; ".join(
        f"{name} {row['impostors']} ({row['memory_bytes'] / 2**20:.2f} MiB, drawn in {row['cpvs']} CPVs)"
        for name, row in rows.items()
    )


def wait_for(client: Client, job_id: str, show_bar: bool) -> dict:
    """Poll the job until it ends, with a progress bar (cells) on a terminal; the job's record
    without its cells while it runs (``?cells=none``: the API does not read a large job's every cell
    twice a second), the whole record once it has ended."""
    bar = tqdm(total=None, desc="cells", unit="cell", disable=None if show_bar else True)
    try:
        while True:
            job = client.request("GET", f"/v1/jobs/{job_id}", params={"cells": "none"}).json()
            bar.total = job["cells_total"]
            bar.update(job["counts"]["done"] + job["counts"]["failed"] + job["counts"]["cancelled"] - bar.n)
            bar.set_postfix_str(placement_line(job) if job["state"] == "placing" else job["state"])
            if job["state"] in ("done", "failed", "cancelled"):
                return client.request("GET", f"/v1/jobs/{job_id}").json()
            time.sleep(0.5)
    finally:
        bar.close()


def download_database(client: Client, job_id: str, directory: Path) -> Path:
    """Fetch the job's impostor database and unpack it into ``directory`` (index.json, cells/NNNNN/...)."""
    data = client.request("GET", f"/v1/jobs/{job_id}/database.zip").content
    directory.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(io.BytesIO(data)) as archive:
        archive.extractall(directory)
    return directory


@click.command("submit")
@click.argument("scene")
@click.option(
    "--technique",
    default=None,
    help="The impostor technique, as the service lists them (`farfield techniques`, GET /v1/techniques) [default: layered].",
)
@click.option("--job-type", default=None, hidden=True, help="Former name of --technique.")
@click.option("--grid", default=None, help="View cells: a grid x0,y0,z0,x1,y1,z1,nx,ny,nz over a view-space box.")
@click.option(
    "--viewcell",
    "viewcells",
    multiple=True,
    help="Or explicit cells (repeat): box:x0,y0,z0,x1,y1,z1 | box-center:... | shaft:...",
)
@click.option("--objects", default=None, help="Comma-separated represented objects (default: all).")
@click.option(
    "--resolution", default=None, type=int, help="Output image pixels per side [default: the technique's, 512]."
)
@click.option(
    "--fov", default=None, type=float, help="Output field of view, degrees [default: the technique's, 45; envmap 90]."
)
@click.option(
    "--option",
    "options",
    multiple=True,
    metavar="NAME=VALUE",
    help="Technique option (repeat); VALUE is parsed as JSON, else taken as text (a list option also takes a,b,c). "
    "`farfield techniques` lists each technique's options.",
)
@click.option(
    "--placement",
    "placement",
    is_flag=True,
    help="A placement job: where impostors of --technique are needed over --view-space for the budget (the flags of `farfield place`); "
    "planned on a worker (state 'placing'), baked, checked and repaired.",
)
@click.option(
    "--view-space", default=None, metavar="X0,Y0,Z0,X1,Y1,Z1", help="With --placement: the box the viewer moves in."
)
@click.option(
    "--frame-ms",
    type=float,
    default=None,
    help="With --placement: every view within this many milliseconds by the cost model.",
)
@click.option(
    "--cost-model",
    default=None,
    help="With --frame-ms: a cost model the service knows by name (llvmpipe, the default) or a model JSON file.",
)
@click.option(
    "--primitives", type=float, default=None, help="With --placement: every view draws at most this many triangles."
)
@click.option(
    "--cpv-size",
    type=float,
    default=None,
    help="With --placement: smallest 3D region of a problem view [default: the view space's longest side / 8].",
)
@click.option(
    "--vdi-deg",
    type=float,
    default=None,
    help="With --placement: smallest view-direction interval, degrees [default: 11.25].",
)
@click.option(
    "--cells",
    "cell_kinds",
    type=click.Choice(["shafts", "boxes", "both", "leaf-boxes"]),
    default=None,
    help="With --placement: view cells of the candidates [default: both].",
)
@click.option(
    "--depth-complexity",
    type=float,
    default=None,
    help="With --placement: a view's estimated covered pixels are at most this many frames [default: 1].",
)
@click.option(
    "--leaf-size",
    type=int,
    default=None,
    help="With --placement: elements per leaf of the object hierarchy [default: 4].",
)
@click.option(
    "--max-impostor-mb",
    type=float,
    default=None,
    help="With --placement: largest impostor considered, MiB by the cost model [default: 32].",
)
@click.option(
    "--also",
    multiple=True,
    metavar="TECHNIQUE[:NAME=VALUE,...]",
    help="With --placement: candidates of another technique beside --technique's (repeatable; as farfield place --also), "
    "e.g. octahedral:grid=9,frame_resolution=16.",
)
@click.option(
    "--cluster-triangles",
    type=int,
    default=None,
    help="With --placement (frame-time): objects over this many triangles are split into elements "
    "[default: max(64, triangles / 256)]; --also lod simplifies hierarchy nodes of 256 triangles or more.",
)
@click.option(
    "--algorithm",
    type=click.Choice(list(ALGORITHMS)),
    default=None,
    help="With --placement: frame-time (seed 000, the default) or primitive-budget (seed 004: LDIs on a solution grid, technique ldi, "
    "every view within --primitives).",
)
@click.option(
    "--p-opt",
    type=float,
    default=None,
    help="primitive-budget: the optimisation budget [default: P less 5 %% of the model, at least P / 2].",
)
@click.option(
    "--octree-depth",
    type=int,
    default=None,
    help="primitive-budget: depth of the octree's pseudo-leaf cells [default: 5].",
)
@click.option(
    "--grid-points",
    type=int,
    default=None,
    help="primitive-budget: initial lattice points along the view space's longest side [default: 3].",
)
@click.option(
    "--max-level",
    type=int,
    default=None,
    help="primitive-budget: deepest subdivision of the solution grid [default: 4].",
)
@click.option(
    "--check-views",
    type=int,
    default=None,
    help="primitive-budget: random views the planner checks the guarantee on [default: 2000].",
)
@click.option(
    "--visibility",
    is_flag=True,
    default=None,
    help="With --placement (frame-time): problem views count only their region's potentially visible set (not conservative).",
)
@click.option(
    "--evaluate/--no-evaluate",
    default=True,
    show_default=True,
    help="Evaluate each baked cell against the real geometry on the worker (layered, tdm): hole pixels, bloat beyond 1 px, "
    "colour error, SSIM in the cell's record. It changes no bundle.",
)
@click.option("--wait", is_flag=True, help="Wait for the job to end (exit code != 0 unless it is done).")
@click.option(
    "--download",
    type=click.Path(file_okay=False),
    default=None,
    help="After --wait, unpack the impostor database here.",
)
@click.option("--json", "as_json", is_flag=True, help="Print the job record as JSON.")
@sides_option
@_client_options
def submit(scene, technique, job_type, grid, viewcells, objects, resolution, fov, options, placement, view_space, frame_ms, cost_model, primitives,
           cpv_size, vdi_deg, cell_kinds, depth_complexity, leaf_size, max_impostor_mb, also, cluster_triangles, algorithm, p_opt, octree_depth, grid_points, max_level,
           check_views, visibility, evaluate, wait, download, as_json, sides, url, key):  # fmt: skip
    """Submit a job for SCENE (a file to upload, or the id of an uploaded scene).  A .gltf or .obj is
    uploaded with the files it refers to (buffers, images; MTL, textures), zipped; --sides goes with
    the upload (an uploaded scene keeps the sidedness it was uploaded with)."""
    client = Client(url, key or _default_key())
    if placement:
        from farfield.cli.place_cmd import parse_also

        if grid is not None or viewcells:
            raise ServiceError("--placement chooses the view cells: leave out --grid and --viewcell")
        if view_space is None:
            raise ServiceError("--placement needs --view-space X0,Y0,Z0,X1,Y1,Z1")
        request = placement_request(view_space, frame_ms, cost_model, primitives, cpv_size, vdi_deg, cell_kinds, depth_complexity, leaf_size, max_impostor_mb,
                                    algorithm, p_opt=p_opt, octree_depth=octree_depth, grid_points=grid_points, max_level=max_level, check_views=check_views,
                                    visibility=True if visibility else None, also=parse_also(also) or None,
                                    cluster_triangles=cluster_triangles)  # fmt: skip
    elif (
        any(
            v is not None
            for v in (algorithm, p_opt, octree_depth, grid_points, max_level, check_views, cluster_triangles)
        )
        or visibility
        or also
    ):
        raise ServiceError(
            "--algorithm, --also, --cluster-triangles, --p-opt, --octree-depth, --grid-points, --max-level, --check-views and "
            "--visibility go with --placement"
        )
    elif (grid is None) == (not viewcells):
        raise ServiceError("give --grid, one or more --viewcell, or --placement")
    parsed = {}
    for item in options:
        name, sep, value = item.partition("=")
        if not sep or not name.strip():
            raise ServiceError(f"--option {item!r}: expected NAME=VALUE")
        name = name.strip()
        try:
            parsed[name] = json.loads(value)
        except ValueError:
            parsed[name] = value
    spec = {
        "technique": technique or job_type, "resolution": resolution, "fov_deg": fov, "options": parsed,
        "objects": object_names(objects),
    }  # fmt: skip
    spec = {k: v for k, v in spec.items() if v is not None}
    if not evaluate:  # sent only when off: the service's default is on
        spec["evaluate"] = False
    if placement:
        spec["placement"] = request
    elif grid is not None:
        spec["grid"] = parse_grid(grid)
    else:
        spec["viewcells"] = [parse_viewcell(v).to_dict() for v in viewcells]
    where = non_finite(spec)
    if where is not None:  # before the upload: a request that cannot be sent leaves nothing behind
        raise ServiceError(f"{where[0]} is {where[1]!r}: the service takes finite numbers only")
    spec["scene_id"] = upload_scene(client, Path(scene), sides) if Path(scene).is_file() else scene
    job = client.request("POST", "/v1/jobs", json=spec).json()
    if not as_json:
        click.echo(f"job {job['id']}: {job['cells_total']} cells, {job['state']}")
    if wait or download:
        job = wait_for(client, job["id"], show_bar=not as_json)
        if download and job["state"] == "done":
            download_database(client, job["id"], Path(download))
    if as_json:
        click.echo(json.dumps({k: v for k, v in job.items() if k != "cells"}))
    elif wait or download:
        click.echo(
            f"job {job['id']}: {job['state']} ({job['counts']['done']}/{job['cells_total']} cells done)"
            + (f", database in {download}" if download and job["state"] == "done" else "")
        )
        if chosen_line(job):
            click.echo(chosen_line(job))
        if job.get("evaluation"):
            click.echo(evaluation_line(job["evaluation"]))
        if job.get("timing"):
            click.echo("\n".join(timing_lines(job["timing"])))
    if (wait or download) and job["state"] != "done":
        first = job["errors"][0]["error"] if job["errors"] else job["state"]
        raise JobEndedBadly(f"job {job['id']} ended {job['state']}: {first}")


def evaluation_line(summary: dict) -> str:
    """One line of a job's evaluation summary (``evaluation`` of a job record).

    >>> print(evaluation_line({"cells": 4, "cells_broken": 1, "hole_pixels": 0, "bloat_beyond_1px": 3,
    ...                        "colour_error_mean": 2.5, "ssim_min": 0.91, "seconds": 1.75}))
    evaluation: 4 cells, 1 breaking the guarantee (0 hole pixels, 3 pixels bloated beyond 1 px); worst colour error mean 2.50, worst SSIM 0.910; 1.75 s
    """
    return (
        f"evaluation: {summary['cells']} cells, {summary['cells_broken']} breaking the guarantee ({summary['hole_pixels']} hole pixels, "
        f"{summary['bloat_beyond_1px']} pixels bloated beyond 1 px); worst colour error mean {summary['colour_error_mean']:.2f}, "
        f"worst SSIM {summary['ssim_min']:.3f}; {summary['seconds']:.2f} s"
    )


def timing_lines(timing: dict) -> list[str]:
    """A job's time broken down (``timing`` of its record, :mod:`farfield.service.jobs.timing`), a short table.

    >>> print("\\n".join(timing_lines({"wall_s": 10.0, "admission_s": 0.5, "planning_s": 0.0, "checking_s": 0.0,
    ...     "cells": 2, "cells_s": 12.0, "cells_busy_s": 8.0, "stages": {"plan": 1.0, "record": 6.0}, "bake_s": 7.0,
    ...     "evaluation_s": 3.0, "overhead_s": 1.5})))
    time                       seconds
      wall                      10.000
      admission                  0.500
      cells (2, summed)         12.000  (busy 8.000: 1.5 at once on average)
        bake: plan               1.000
        bake: record             6.000
        evaluation               3.000
      overhead                   1.500
    """
    rows = [("wall", timing["wall_s"], "")]
    rows += [(name, timing[f"{name}_s"], "") for name in ("admission", "planning") if timing[f"{name}_s"]]
    busy = timing["cells_busy_s"]
    at_once = f"  (busy {busy:.3f}: {timing['cells_s'] / busy:.1f} at once on average)" if busy > 0 else ""
    rows.append((f"cells ({timing['cells']}, summed)", timing["cells_s"], at_once))
    rows += [(f"  bake: {name}", seconds, "") for name, seconds in timing["stages"].items()]
    if timing["evaluation_s"]:
        rows.append(("  evaluation", timing["evaluation_s"], ""))
    if timing["checking_s"]:
        rows.append(("checking", timing["checking_s"], ""))
    rows.append(("overhead", timing["overhead_s"], ""))
    return [f"{'time':<25}{'seconds':>9}"] + [f"  {label:<22} {seconds:>9.3f}{note}" for label, seconds, note in rows]


@click.command("jobs")
@click.argument("job_id", required=False)
@click.option("--state", default=None, help="Only jobs in this state.")
@click.option("--json", "as_json", is_flag=True)
@_paging_options
@_client_options
def jobs(job_id, state, as_json, limit, offset, every, url, key):
    """List jobs, newest first, or show JOB_ID."""
    client = Client(url, key or _default_key())
    if job_id:
        job = client.request("GET", f"/v1/jobs/{job_id}").json()
        if as_json:
            click.echo(json.dumps(job))
            return
        click.echo(f"{job['id']}  {job['state']}  {job['counts']}  progress {job['progress']:.0%}")
        if placement_line(job):
            click.echo(f"  {placement_line(job)}")
        if chosen_line(job):
            click.echo(f"  {chosen_line(job)}")
        if job.get("error"):
            click.echo(f"  error: {job['error']}")
        if job.get("evaluation"):
            click.echo(f"  {evaluation_line(job['evaluation'])}")
        if job.get("timing"):
            click.echo("\n".join(f"  {line}" for line in timing_lines(job["timing"])))
        for error in job["errors"]:
            click.echo(f"  cell {error['index']}: {error['error']}")
        return
    _listing(client, "/v1/jobs", {"state": state} if state else None, (limit, offset, every), "jobs", as_json,
             lambda job: f"{job['id']}  {job['state']:<9}  {job['counts']['done']}/{job['cells_total']} cells  {job['progress']:.0%}")  # fmt: skip


def _write_demo(names, out, size, seed, detail, as_json) -> None:
    """``farfield scenes demo NAME --out FILE``."""
    from farfield.core.exchange.export import scene_glb
    from farfield.core.procedural import DEMOS, demo_scene

    if len(names) != 1 or names[0] not in DEMOS:
        raise FarfieldError(
            "farfield scenes demo NAME --out FILE.glb: NAME is one of "
            + "; ".join(f"{k} ({v})" for k, v in DEMOS.items())
        )
    if out is None:
        raise FarfieldError("farfield scenes demo needs --out FILE.glb")
    if not out.lower().endswith(".glb"):
        raise FarfieldError(f"--out {out!r}: the demo scenes are written as GLB; give a .glb file name")
    if names[0] == "house" and size is not None:
        raise FarfieldError("--size applies to the city (buildings) and the forest (trees), not the house")
    scene = demo_scene(names[0], size, seed, detail)
    path = Path(out)
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(f".{path.name}.part")
    temporary.write_bytes(scene_glb(scene))
    temporary.replace(path)  # nothing half-written
    summary = {
        "scene": names[0],
        "out": str(path),
        "objects": scene.object_count,
        "triangles": scene.triangle_count,
        "bounds": scene.bounds.tolist(),
    }
    if as_json:
        click.echo(json.dumps(summary))
    else:
        lo, hi = scene.bounds
        click.echo(
            f"{path}: {names[0]}, {scene.object_count} objects, {scene.triangle_count:,} triangles, bounds {lo.round(3).tolist()} .. {hi.round(3).tolist()}"
        )


@click.command("scenes")
@click.argument("words", nargs=-1, metavar="[SCENE_ID | demo NAME]")
@click.option("--objects", "with_objects", is_flag=True, help="With SCENE_ID: list its objects (paged like scenes).")
@click.option("--out", default=None, type=click.Path(dir_okay=False), help="demo: the GLB file to write.")
@click.option(
    "--size",
    default=None,
    type=click.IntRange(min=1),
    help="demo: buildings of the city [300] or trees of the forest [200].",
)
@click.option("--seed", default=None, type=int, help="demo: the random seed [city 0, house 4, forest 1].")
@click.option(
    "--detail",
    default=1,
    show_default=True,
    type=click.IntRange(min=1, max=64),
    help="demo city: most quads per building face side.",
)
@click.option("--json", "as_json", is_flag=True)
@_paging_options
@_client_options
def scenes(words, with_objects, out, size, seed, detail, as_json, limit, offset, every, url, key):
    """List scenes, newest first, or show SCENE_ID (and its objects).

    `farfield scenes demo city|house|forest --out FILE.glb` writes a procedural scene (no service
    needed): the city, house and forest the README's examples and the benchmarks use."""
    if words and words[0] == "demo":
        if with_objects:
            raise FarfieldError("--objects goes with a SCENE_ID, not with 'farfield scenes demo'")
        _write_demo(words[1:], out, size, seed, detail, as_json)
        return
    if len(words) > 1:
        raise FarfieldError(f"expected one SCENE_ID (or 'demo NAME'), got {' '.join(words)}")
    if out is not None or size is not None or seed is not None or detail != 1:
        raise FarfieldError("--out, --size, --seed and --detail go with 'farfield scenes demo NAME'")
    scene_id = words[0] if words else None
    client = Client(url, key or _default_key())
    if scene_id and with_objects:
        _listing(client, f"/v1/scenes/{scene_id}/objects", None, (limit, offset, every), "objects", as_json,
                 lambda obj: f"{obj['name']}  {obj['triangles']} triangles  bounds {obj['bounds']}")  # fmt: skip
        return
    rows, total = (
        ([client.request("GET", f"/v1/scenes/{scene_id}").json()], 1)
        if scene_id
        else client.pages("/v1/scenes", None, limit, offset, every)
    )
    if not scene_id:
        _more(len(rows), offset, total, "scenes")
    if as_json:
        click.echo(json.dumps(rows[0] if scene_id else rows))
        return
    for scene in rows:
        click.echo(
            f"{scene['id']}  {scene['name']}  {scene['object_count']} objects  {scene['triangles']} triangles  {scene['size_bytes']} bytes"
        )
