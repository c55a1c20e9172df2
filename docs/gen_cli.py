"""The command-line reference (docs/reference/cli.md), generated from madp's typer app.

``python docs/gen_cli.py`` rewrites the page; ``python docs/gen_cli.py --check`` exits 1 when the
committed page differs from what the app says now. The site's build (docs/hooks.py) and
tests/test_docs.py run the check, so the page cannot drift from the code."""

from __future__ import annotations

import sys
from pathlib import Path

PAGE = Path(__file__).resolve().parent / "reference" / "cli.md"
WIDTH = 100

HEADER = """# Command line

Every `madp` command and option, as `madp … --help` prints them. Generated from the command line
itself by `python docs/gen_cli.py`; the site's build and the tests fail when this page and the code
differ.
"""


def commands():
    """``(path, click command, click context)`` of every command of ``madp``, depth first, in the
    order the help lists them."""
    import typer

    from madp.cli import app
    from madp.commands.main import _click

    click = _click()  # click as typer runs it
    root = typer.main.get_command(app)
    out = []

    def walk(cmd, path, parent):
        ctx = click.Context(cmd, info_name=path[-1], parent=parent, terminal_width=WIDTH, max_content_width=WIDTH)
        out.append((path, cmd, ctx))
        for name in getattr(cmd, "list_commands", lambda _: [])(ctx):
            sub = cmd.get_command(ctx, name)
            if sub is not None and not getattr(sub, "hidden", False):
                walk(sub, path + [name], ctx)

    walk(root, ["madp"], None)
    return out


def render() -> str:
    parts = [HEADER]
    for path, cmd, ctx in commands():
        level = "#" * min(len(path) + 1, 4)
        parts.append(f"{level} `{' '.join(path)}`\n\n```text\n{cmd.get_help(ctx).rstrip()}\n```\n")
    return "\n".join(parts)


def main(argv: list[str]) -> int:
    text = render()
    if "--check" in argv:
        if PAGE.read_text(encoding="utf-8") != text:
            print(f"{PAGE} differs from the command line; run python docs/gen_cli.py", file=sys.stderr)
            return 1
        return 0
    PAGE.write_text(text, encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
