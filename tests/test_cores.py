"""Thread pools of compiled kernels size themselves by the cores the process may use (its affinity),
not by the machine's count (farfield.core.cores)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest


@pytest.mark.skipif(not hasattr(os, "sched_setaffinity"), reason="no CPU affinity on this platform")
def test_a_process_pinned_to_one_core_counts_one():
    script = (
        "import os; os.sched_setaffinity(0, {min(os.sched_getaffinity(0))}); "
        "from farfield.core.cores import usable_cores; from farfield.core.impostor.png_pages import thread_count; "
        "print(usable_cores(), thread_count())"
    )
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True).stdout.split()
    assert out == ["1", "4"]  # one core; the PNG writer's threads still at least 4 (they wait on fsync)
