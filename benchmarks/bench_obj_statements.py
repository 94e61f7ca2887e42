"""CPU seconds of the OBJ text's statement pass (``farfield.core.exchange.obj.plain_statements``):
ordinary files with comments, and lines that made its regexes backtrack over the square of their length.

Usage: ``.venv/bin/python benchmarks/bench_obj_statements.py [--lines 1000000] [--widest 1000000]``

Rows: a file of ``--lines`` ``v`` lines each ending in a ``# comment`` (the trailing-comment
pattern on every line), the same with ``\\`` continued faces (the comment pass too), and one
``v`` line padded with N spaces in a file holding a mid-line ``#``, and one comment of N
backslashes in a file holding a continued line (each a 1-10 MB upload).  Each row: the best of 3
(``time.process_time``).  Run it on two commits to compare them.
"""

from __future__ import annotations

import argparse
import time

from farfield.core.exchange.obj import plain_statements


def _seconds(text: str, repeats: int = 3) -> float:
    best = float("inf")
    for _ in range(repeats):
        begun = time.process_time()
        plain_statements(text)
        best = min(best, time.process_time() - begun)
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lines", type=int, default=1_000_000)
    parser.add_argument("--widest", type=int, default=1_000_000, help="the longest padded line (0: none past 40,000)")
    args = parser.parse_args()
    n = args.lines
    rows = {
        f"{n:,} v lines, each with a # comment": "".join(f"v {k} 0 0 # corner {k}\n" for k in range(n)),
        "the same and a continued face (\\\\)": "".join(f"v {k} 0 0 # corner {k}\n" for k in range(n))
        + "f 1 2 \\\n 3\n",
    }
    for width in (10_000, 20_000, 40_000, *([args.widest] if args.widest > 40_000 else [])):
        rows[f"one v line of {width:,} spaces, a # mid-line"] = "v " + " " * width + "0 1 0\nf 1 2 3 # c\n"
        rows[f"one comment of {width:,} backslashes, a \\\\ line"] = "# " + "\\" * width + "x\nf 1 2 \\\n 3\n"
    print("| text | CPU s |\n| --- | ---: |")
    for name, text in rows.items():
        print(f"| {name} | {_seconds(text):.3f} |", flush=True)


if __name__ == "__main__":
    main()
