"""Shared pytest configuration: the test tiers, a report header that says where the suite ran
(machine, libraries), the session's EGL context, numba warm-up, chromium and three.js page, and the
glTF validator run on every GLB a test writes (``tests/glb_validation.py``): a test that leaves an
invalid one under pytest's temporary directories fails at teardown with the validator's messages,
unless it is marked ``invalid_glb`` (it writes broken files on purpose).

Tiers.  ``./run-tests`` runs everything (CI: ``.ci/run``); ``./run-tests --fast`` runs
``-m "not service and not browser and not slow"``: the unit and render tests, about 2 minutes
on a 2-core CPU machine (llvmpipe).  The markers (registered in pyproject.toml):

- ``service``: starts the service (``farfield up``: redis, celery workers, the API).  Set here on
  every test that uses a fixture of ``tests/service_harness.py`` (``service``, ``client``); a test
  that calls :func:`service_harness.start_service` itself marks itself (``start_service`` refuses to
  run in an unmarked test).
- ``browser``: needs chromium (Playwright; the dashboard and the three.js harness).  Set here on
  every test that uses the ``browser`` or ``threejs`` fixture.
- ``slow``: anything else that takes long (over about 2 s on that machine: subprocess CLIs, the
  wheel build, large bakes, the golden bytes, the README's examples), set by hand per module
  (``pytestmark``) or per test after a ``--durations`` run; mark a new test that takes as long.

Fixtures that cost seconds are session fixtures, made only for the tests that use them:
``numba_kernels`` fills numba's cache (the TDM, point, LDI and recording kernels) once, before the
service fixtures start render workers (:func:`farfield.workers.tasks.warm_worker` then loads them
instead of compiling); ``gl`` is this process's EGL context (a test that renders through the library
makes it lazily anyway; the renderer it ran on is printed at the end of the run)."""

from __future__ import annotations

import os
import platform
import sys

import numpy
import pytest
import scipy
import trimesh

# Fixtures whose use puts a test in a tier: (module, fixture function) -> marker.
_TIER_FIXTURES = {("service_harness", None): "service", ("conftest", "browser"): "browser"}


def pytest_configure(config):
    config.addinivalue_line(
        "markers",
        "invalid_glb: writes broken GLB files on purpose (exempt from the glTF validator run on every GLB a test writes)",
    )


def _tier_of(fixturedef) -> str | None:
    module = getattr(fixturedef.func, "__module__", "").rpartition(".")[2]
    name = getattr(fixturedef.func, "__name__", "")
    return _TIER_FIXTURES.get((module, None)) or _TIER_FIXTURES.get((module, name))


def pytest_collection_modifyitems(config, items):
    """Mark each test with the tier of the fixtures it uses (directly or through other fixtures)."""
    for item in items:
        info = getattr(item, "_fixtureinfo", None)
        if info is None:
            continue
        tiers = {_tier_of(defs[-1]) for name in item.fixturenames if (defs := info.name2fixturedefs.get(name))}
        for tier in sorted(tiers - {None}):
            if item.get_closest_marker(tier) is None:
                item.add_marker(tier)


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item):
    import service_harness

    service_harness.SERVICE_TIER = item.get_closest_marker("service") is not None


def pytest_report_header(config):
    # Cheap only: no GL context and no numba compilation here (session fixtures make those, for
    # the tests that need them; the renderer is reported in the terminal summary).
    lines = [
        f"farfield on {platform.platform()} ({platform.machine()}), Python {sys.version.split()[0]}",
        f"numpy {numpy.__version__}, scipy {scipy.__version__}, trimesh {trimesh.__version__}",
    ]
    from threejs import installed_versions

    versions = installed_versions()
    lines.append(
        "npm (tests/js): "
        + (", ".join(f"{k} {v}" for k, v in versions.items()) or "not installed (scripts/install-js)")
    )
    return lines


_NUMBA_SECONDS = pytest.StashKey()


@pytest.fixture(scope="session")
def numba_kernels(request) -> float:
    """Fill numba's cache with the TDM, point, LDI and recording kernels once per session (seconds
    taken): the render workers the service tests start then load them (``warm_worker``) instead of
    each compiling them while a test waits."""
    from service_harness import warm_numba_kernels

    seconds = warm_numba_kernels()
    request.config.stash[_NUMBA_SECONDS] = seconds
    return seconds


@pytest.fixture(scope="module")
def service_env() -> dict:
    """More environment for the module's ``service`` fixture (service_harness.py): override it in a
    test module (e.g. ``{"FARFIELD_REQUEUE_AFTER": "2"}``)."""
    return {}


@pytest.fixture(scope="session")
def gl():
    """This process's EGL context (:func:`farfield.core.render.context.gl_context`), made once.
    pytest's own process never forks after it (the service runs in ``farfield up`` subprocesses)."""
    from farfield.core.render.context import gl_context

    return gl_context()


def _renderer_line() -> str | None:
    """The renderer of this process's GL context if a test made one (never makes one)."""
    context = sys.modules.get("farfield.core.render.context")
    if context is None or context._context is None or context._owner_pid != os.getpid():
        return None
    info = context.renderer_info()
    return f"OpenGL: {info.renderer} | {info.version} | {info.vendor}"


_GLB_WATCH = pytest.StashKey()


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    renderer = _renderer_line()
    if renderer is not None:
        terminalreporter.write_line(renderer)
    seconds = config.stash.get(_NUMBA_SECONDS, None)
    if seconds is not None:
        terminalreporter.write_line(f"numba kernels ready in {seconds:.1f} s (session fixture numba_kernels)")
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
