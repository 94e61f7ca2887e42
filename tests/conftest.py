"""Shared pytest configuration: a report header that says where the suite ran."""

from __future__ import annotations

import platform
import sys

import numpy
import scipy
import trimesh


def pytest_report_header(config):
    return [
        f"farfield on {platform.platform()} ({platform.machine()}), Python {sys.version.split()[0]}",
        f"numpy {numpy.__version__}, scipy {scipy.__version__}, trimesh {trimesh.__version__}",
    ]
