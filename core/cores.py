"""The CPU cores this process may use: its affinity mask where the platform has one (a container's
or ``taskset``'s limit, a Celery worker pinned to some cores), else the machine's count.  Thread
pools of compiled (``nogil``) kernels size themselves by it, so a pinned process does not run more
busy threads than it has cores.

>>> usable_cores() >= 1
True
"""

from __future__ import annotations

import os


def usable_cores() -> int:
    """Cores this process may run on (at least 1)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1
