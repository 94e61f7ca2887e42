"""Shared pytest configuration: a report header that says where the suite ran (machine, libraries, GL renderer)."""

from __future__ import annotations

import platform
import sys

import numpy
import pytest
import scipy
import trimesh


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
    return lines


@pytest.fixture(scope="session")
def browser():
    """One headless chromium for the session's dashboard tests (skipped without it or Playwright)."""
    from browser import CHROMIUM, SKIP_REASON, launched_browser

    if not CHROMIUM.exists():
        pytest.skip(SKIP_REASON)
    pytest.importorskip("playwright.sync_api", reason="needs the playwright package (the test extra)")
    with launched_browser() as launched:
        yield launched
