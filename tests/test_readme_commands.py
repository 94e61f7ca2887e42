"""The README's offline examples run as written (issue 30: "every README command runs as written on
a fresh clone").

Every ``sh`` block of README.md is read; its ``./farfield`` commands that need no running service
are run in order, in a fresh folder beside a link to ``../shared`` (as the README's commands sit in
the checkout, next to ``shared/``), with this test session's Python in place of the ``./farfield``
wrapper (which only sets up ``.venv`` first).  A command fails the test when it exits non-zero or
prints a traceback.  The service's commands (``up``, ``submit``, ``jobs``, ``scenes`` without
``demo``, and the walkthroughs of what ``submit`` downloads) run in the service tests instead;
lines that show a command's grammar (``city|house|forest``, ``[ID ...]``) are not commands.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
SERVICE = {"up", "submit", "jobs", "keys", "worker"}


def readme_commands() -> list[str]:
    """The ``./farfield`` command lines of README.md's ``sh`` blocks, continuation lines joined and
    comments cut, in order."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    commands = []
    for block in re.findall(r"^```sh\n(.*?)^```", text, flags=re.S | re.M):
        joined = re.sub(r"\\\n\s*", " ", block)
        for line in joined.splitlines():
            line = line.split(" #", 1)[0].strip()
            if line.startswith("./farfield "):
                commands.append(line)
    return commands


def offline(command: str) -> bool:
    """Whether ``command`` runs without a service and is a command rather than a grammar line."""
    words = shlex.split(command)
    if len(words) < 2 or words[1] in SERVICE or any(ch in command for ch in "|[]"):
        return False
    if words[1] == "scenes" and (len(words) < 3 or words[2] != "demo"):
        return False
    # a walkthrough of a database that `submit --download` wrote needs the service's job
    return not (words[1] == "walkthrough" and words[2].startswith("out/city-"))


def test_the_readme_lists_offline_examples():
    commands = [c for c in readme_commands() if offline(c)]
    assert len(commands) >= 10, commands
    assert any(c.startswith("./farfield scenes demo house") for c in commands)
    assert any(c.startswith("./farfield glb ") for c in commands)


@pytest.mark.skipif(not (SHARED / "scenes").is_dir(), reason="needs ../shared/scenes")
@pytest.mark.slow
def test_the_readme_offline_examples_run_as_written(tmp_path):
    work = tmp_path / "checkout"
    work.mkdir()
    (tmp_path / "shared").symlink_to(SHARED, target_is_directory=True)
    env = {k: v for k, v in os.environ.items() if not k.startswith("FARFIELD_")}
    for command in (c for c in readme_commands() if offline(c)):
        words = shlex.split(command)
        done = subprocess.run([sys.executable, "-m", "farfield.cli.main", *words[1:]], cwd=work, env=env, capture_output=True, text=True, timeout=900)
        assert done.returncode == 0 and "Traceback" not in done.stderr, f"{command}\n{done.stdout[-2000:]}\n{done.stderr[-2000:]}"
    assert (work / "out" / "layered-compressed.glb").is_file() and (work / "house.glb").is_file()
