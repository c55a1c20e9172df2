"""MkDocs hook: the build fails when the command-line reference differs from madp's typer app."""

from __future__ import annotations

import importlib.util
from pathlib import Path


def on_pre_build(config, **kwargs) -> None:
    spec = importlib.util.spec_from_file_location("gen_cli", Path(__file__).with_name("gen_cli.py"))
    gen = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(gen)
    if gen.PAGE.read_text(encoding="utf-8") != gen.render():
        from mkdocs.exceptions import PluginError

        raise PluginError(f"{gen.PAGE} differs from the command line: run python docs/gen_cli.py")
