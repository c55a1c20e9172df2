"""MkDocs hooks: the build fails when the command-line reference differs from madp's typer app, when a
generated results table differs from what ``madp eval report`` writes from the kept results, and when
the built site holds a compiled Python file, a file over 1 MB (large files are linked, not copied) or
the word SPEC (a docstring pointing at the project's internal specification)."""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

DOCS = Path(__file__).resolve().parent
MAX_FILE_BYTES = 1_000_000


def _fail(message: str) -> None:
    from mkdocs.exceptions import PluginError

    raise PluginError(message)


def on_pre_build(config, **kwargs) -> None:
    spec = importlib.util.spec_from_file_location("gen_cli", DOCS / "gen_cli.py")
    gen = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(gen)
    if gen.PAGE.read_text(encoding="utf-8") != gen.render():
        _fail(f"{gen.PAGE} differs from the command line: run python docs/gen_cli.py")
    from madp.results.pages import load_kept, render, update_pages

    stale = update_pages([DOCS.parent / "README.md", DOCS], render(load_kept(DOCS / "results")), check=True)
    if stale:
        _fail(f"results tables differ from docs/results in {', '.join(map(str, stale))}: run madp eval report")


def on_post_build(config, **kwargs) -> None:
    site = Path(config["site_dir"])
    for source_map in site.glob("assets/**/*.map"):  # the theme's JavaScript source maps: for debugging the theme only
        source_map.unlink()
    bad = [f"{p.relative_to(site)} ({p.stat().st_size} bytes)" for p in site.rglob("*")
           if p.is_file() and (p.suffix == ".pyc" or p.stat().st_size > MAX_FILE_BYTES)]
    if bad:
        _fail(f"the site must not publish compiled Python or files over 1 MB (exclude_docs in mkdocs.yml): {bad}")
    internal = [str(p.relative_to(site)) for p in site.rglob("*.html") if re.search(r"\bSPEC\b", p.read_text(encoding="utf-8"))]
    if internal:  # the API pages render docstrings: they too must not point at the project's internal specification
        _fail(f"the site names SPEC, which a reader cannot follow: {internal}")
