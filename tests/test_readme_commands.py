"""The README's and the docs' offline examples run as written (issue 30: "every README command runs
as written on a fresh clone"; issue 53: "tests/test_readme_commands.py keeps running every offline
command of the README and of the docs' sh blocks").

Every ``sh`` block of README.md, then of every page under ``docs/`` (in path order), is read; its
``./farfield`` commands that need no running service are run in that order, each distinct command
once, in a fresh folder beside a link to ``../shared`` (as the commands sit in the checkout, next to
``shared/``), with this test session's Python in place of the ``./farfield`` wrapper (which only
sets up ``.venv`` first).  A command fails the test when it exits non-zero or prints a traceback.
The service's commands (``up``, ``submit``, ``jobs``, ``scenes`` without ``demo``, and the
walkthroughs of what ``submit`` downloads) run in the service tests instead; lines that show a
command's grammar (``city|house|forest``, ``[ID ...]``) are not commands.
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


def documents() -> list[Path]:
    """README.md, then every Markdown page of docs/ in path order."""
    return [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]


def sh_commands(path: Path) -> list[str]:
    """The ``./farfield`` command lines of ``path``'s ``sh`` blocks, continuation lines joined and
    comments cut, in order."""
    text = path.read_text(encoding="utf-8")
    commands = []
    for block in re.findall(r"^```sh\n(.*?)^```", text, flags=re.S | re.M):
        joined = re.sub(r"\\\n\s*", " ", block)
        for line in joined.splitlines():
            line = line.split(" #", 1)[0].strip()
            if line.startswith("./farfield "):
                commands.append(line)
    return commands


def readme_commands() -> list[str]:
    return sh_commands(ROOT / "README.md")


def offline(command: str) -> bool:
    """Whether ``command`` runs without a service and is a command rather than a grammar line."""
    words = shlex.split(command)
    if len(words) < 2 or words[1] in SERVICE or any(ch in command for ch in "|[]"):
        return False
    if words[1] == "scenes" and (len(words) < 3 or words[2] != "demo"):
        return False
    # a walkthrough of a database that `submit --download` wrote needs the service's job
    return not (words[1] == "walkthrough" and words[2].startswith("out/city-"))


def offline_commands() -> list[str]:
    """The distinct offline commands of README.md and docs/, in reading order."""
    seen: dict[str, None] = {}
    for path in documents():
        for command in sh_commands(path):
            if offline(command):
                seen.setdefault(" ".join(shlex.split(command)))
    return list(seen)


def test_the_readme_is_a_guide_with_offline_examples():
    assert len((ROOT / "README.md").read_text(encoding="utf-8").splitlines()) <= 250
    commands = [c for c in readme_commands() if offline(c)]
    assert len(commands) >= 6, commands
    # the two commands, exactly as they are
    assert "./farfield up" in readme_commands() and "./run-tests" in (ROOT / "README.md").read_text(encoding="utf-8")
    # the tour: a demo scene, a bake, an evaluate, a glb
    for start in ("./farfield scenes demo house", "./farfield bake ", "./farfield evaluate ", "./farfield glb "):
        assert any(c.startswith(start) for c in commands), (start, commands)
    # and the service's half of it: a placement job
    assert any(c.startswith("./farfield submit ") and "--placement" in c for c in readme_commands())


def test_the_docs_list_offline_examples():
    pages = [p for p in documents()[1:] if any(offline(c) for c in sh_commands(p))]
    assert len(pages) >= 3, pages
    commands = offline_commands()
    assert len(commands) >= 12, commands
    for verb in ("layers", "bake", "evaluate", "glb", "inspect", "scenes"):
        assert any(shlex.split(c)[1] == verb for c in commands), (verb, commands)


def test_the_docs_links_lead_somewhere():
    """Every relative link of README.md, CHANGELOG.md and docs/ names a file of the checkout (links
    to ``../shared`` aside), and every page of docs/ is linked from its index or the README."""
    linked, broken = set(), []
    for page in [*documents(), ROOT / "CHANGELOG.md"]:
        for target in re.findall(r"\]\(([^)\s]+)\)", page.read_text(encoding="utf-8")):
            path = target.split("#", 1)[0]
            if not path or target.startswith(("http://", "https://", "mailto:")):
                continue
            resolved = (page.parent / path).resolve()
            if not resolved.is_relative_to(ROOT):
                continue
            linked.add(resolved)
            if not resolved.exists():
                broken.append(f"{page.relative_to(ROOT)}: {target}")
    assert not broken, broken
    assert not [str(p.relative_to(ROOT)) for p in documents()[1:] if p.resolve() not in linked]


@pytest.mark.skipif(not (SHARED / "scenes").is_dir(), reason="needs ../shared/scenes")
@pytest.mark.slow
def test_the_offline_examples_run_as_written(tmp_path):
    work = tmp_path / "checkout"
    work.mkdir()
    (tmp_path / "shared").symlink_to(SHARED, target_is_directory=True)
    env = {k: v for k, v in os.environ.items() if not k.startswith("FARFIELD_")}
    for command in offline_commands():
        words = shlex.split(command)
        done = subprocess.run(
            [sys.executable, "-m", "farfield.cli.main", *words[1:]],
            cwd=work,
            env=env,
            capture_output=True,
            text=True,
            timeout=900,
        )
        assert done.returncode == 0 and "Traceback" not in done.stderr, (
            f"{command}\n{done.stdout[-2000:]}\n{done.stderr[-2000:]}"
        )
    assert (work / "out" / "layered-compressed.glb").is_file() and (work / "house.glb").is_file()
