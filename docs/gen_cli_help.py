"""Rewrite the ``$ weldcell ... --help`` blocks of docs/cli.md from the installed command itself.

Every fenced block in docs/cli.md whose first line is ``$ weldcell <words> --help`` is replaced by that
command's help text at 80 columns; the rest of the page (prose, example runs) is left alone.

    python docs/gen_cli_help.py            rewrite docs/cli.md
    python docs/gen_cli_help.py --check    exit 1 when a help block is out of date
"""

from __future__ import annotations

import argparse
import difflib
import re
import sys
from pathlib import Path

from click.testing import CliRunner

PAGE = Path(__file__).resolve().parent / "cli.md"
FENCE = re.compile(r"```\n(?P<body>\$ .*?)```", re.S)
COMMAND = re.compile(r"^\$ .*$", re.M)


def help_text(args: list[str]) -> str:
    """``weldcell ARGS`` as a user's 80-column terminal shows it."""
    from weldcell.sdk.cli import main

    result = CliRunner().invoke(main, args, terminal_width=78, prog_name="weldcell")
    if result.exit_code != 0:
        raise SystemExit(f"weldcell {' '.join(args)} failed ({result.exit_code}):\n{result.output}")
    return result.output


def _fence(body: str) -> str:
    """A fenced block of ``$ command`` lines, each followed by its output: --help outputs rewritten."""
    starts = [m.start() for m in COMMAND.finditer(body)] + [len(body)]
    out = []
    for a, b in zip(starts[:-1], starts[1:], strict=True):
        segment = body[a:b]
        command = segment.split("\n", 1)[0]
        words = command[2:].split()
        if words[:1] == ["weldcell"] and words[-1:] == ["--help"]:
            segment = f"{command}\n{help_text(words[1:])}"
        out.append(segment)
    return "".join(out)


def render(page: str) -> str:
    """``page`` with every ``weldcell ... --help`` output rewritten."""
    return FENCE.sub(lambda m: f"```\n{_fence(m['body'])}```", page)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="exit 1 when docs/cli.md is out of date")
    a = ap.parse_args()
    old = PAGE.read_text()
    new = render(old)
    if a.check:
        if new != old:
            diff = difflib.unified_diff(
                old.splitlines(), new.splitlines(), "docs/cli.md", "generated", lineterm=""
            )
            sys.stderr.write("\n".join(diff) + "\n")
            return 1
        return 0
    PAGE.write_text(new)
    return 0


if __name__ == "__main__":
    sys.exit(main())
