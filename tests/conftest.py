"""Shared pytest configuration: a report header that says where the suite ran (machine, libraries, GL
renderer), the session's chromium and three.js page, and the glTF validator run on every GLB a test
writes (``tests/glb_validation.py``): a test that leaves an invalid one under pytest's temporary
directories fails at teardown with the validator's messages, unless it is marked ``invalid_glb``
(it writes broken files on purpose).  The header also fills numba's cache (the TDM kernels) before
any test starts a render worker."""

from __future__ import annotations

import platform
import sys

import numpy
import pytest
import scipy
import trimesh


def pytest_configure(config):
    config.addinivalue_line(
        "markers",
        "invalid_glb: writes broken GLB files on purpose (exempt from the glTF validator run on every GLB a test writes)",
    )


def pytest_report_header(config):
    lines = [
        f"farfield on {platform.platform()} ({platform.machine()}), Python {sys.version.split()[0]}",
        f"numpy {numpy.__version__}, scipy {scipy.__version__}, trimesh {trimesh.__version__}",
    ]
    # Asking for the renderer creates this process's EGL context; pytest does not fork afterwards.
    from farfield.core.errors import RenderBackendError
    from farfield.core.render.context import renderer_info

    try:
        info = renderer_info()
        lines.append(f"OpenGL: {info.renderer} | {info.version} | {info.vendor}")
    except RenderBackendError as error:
        lines.append(f"OpenGL: unavailable ({error})")
    from threejs import installed_versions

    versions = installed_versions()
    lines.append(
        "npm (tests/js): "
        + (", ".join(f"{k} {v}" for k, v in versions.items()) or "not installed (scripts/install-js)")
    )
    # Fill numba's cache once here, so the render workers the service tests start load the TDM,
    # point and recording kernels (warm_worker) instead of each compiling them while a test waits.
    from farfield.core.layering import recording
    from farfield.core.techniques import ldi
    from farfield.core.techniques.points import technique as points
    from farfield.core.techniques.tdm import technique as tdm

    lines.append(
        f"numba kernels ready in {tdm.warm_kernels() + points.warm_kernels() + ldi.warm_kernels() + recording.warm_kernels():.1f} s"
    )
    return lines


_GLB_WATCH = pytest.StashKey()


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    watch = config.stash.get(_GLB_WATCH, None)
    if watch is not None:
        terminalreporter.write_line(
            f"glTF validator {watch.validator.version if watch.validator else ''}: {watch.files_checked} GLB files "
            f"written by tests checked, {len(watch.flagged)} with errors or warnings ({watch.seconds:.1f} s)"
        )


@pytest.fixture(scope="session")
def glb_watch(request, tmp_path_factory):
    """The session's :class:`glb_validation.GlbWatch` over pytest's base temporary directory
    (None without node or the validator: nothing is validated then)."""
    from glb_validation import GlbWatch
    from threejs import validator_available

    watch = GlbWatch(tmp_path_factory.getbasetemp()) if validator_available() else None
    request.config.stash[_GLB_WATCH] = watch
    yield watch
    if watch is not None:
        watch.close()


@pytest.fixture(scope="session")
def gltf_validator(glb_watch):
    """The session's :class:`glb_validation.GltfValidator` (skipped without node or the validator)."""
    from threejs import VALIDATOR_SKIP_REASON

    if glb_watch is None:
        pytest.skip(VALIDATOR_SKIP_REASON)
    return glb_watch.started()


@pytest.fixture(autouse=True)
def glb_files_are_valid(request, glb_watch):
    """After each test: every GLB new or changed under pytest's temporary directories passes the
    Khronos validator with 0 errors and 0 warnings (a test marked ``invalid_glb`` is exempt)."""
    yield
    if glb_watch is None:
        return
    own = [request.node.funcargs[name] for name in ("tmp_path", "tmpdir") if name in request.node.funcargs]
    bad = glb_watch.check(finished=[str(path) for path in own])
    if bad and request.node.get_closest_marker("invalid_glb") is None:
        lines = [f"{path}:\n  " + "\n  ".join(found) for path, found in sorted(bad.items())]
        pytest.fail(
            "the glTF validator finds errors or warnings in GLB files written during this test:\n" + "\n".join(lines),
            pytrace=False,
        )


@pytest.fixture(scope="session")
def browser():
    """One headless chromium for the session's dashboard and three.js tests (skipped without it or Playwright)."""
    from browser import CHROMIUM, SKIP_REASON, launched_browser

    if not CHROMIUM.exists():
        pytest.skip(SKIP_REASON)
    pytest.importorskip("playwright.sync_api", reason="needs the playwright package (the test extra)")
    with launched_browser() as launched:
        yield launched


@pytest.fixture(scope="session")
def threejs(browser):
    """One three.js page in the session's chromium (:class:`threejs.ThreeRenderer`); skipped
    without the pinned npm packages."""
    from threejs import THREE_SKIP_REASON, ThreeRenderer, three_available

    if not three_available():
        pytest.skip(THREE_SKIP_REASON)
    renderer = ThreeRenderer(browser)
    yield renderer
    renderer.close()
