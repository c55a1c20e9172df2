"""The documentation cannot drift from the code: every ``madp …`` command line in the README and the
site's code blocks names commands and options that exist, the command-line reference is what the app
says, the extension guide's examples run, and the README stays short."""

from __future__ import annotations

import importlib.util
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest
import typer

from madp.cli import app

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
PAGES = [ROOT / "README.md", *sorted(DOCS.rglob("*.md"))]
SHELLS = {"", "bash", "sh", "shell", "console"}
OPERATORS = {"|", "||", "&&", ";", "&", ">", ">>", "<", "(", ")"}


def code_blocks(text: str, languages: set[str]) -> list[str]:
    """The fenced code blocks (```` ```lang ````, indented or not) of a Markdown text in ``languages``."""
    blocks, language, lines = [], None, []
    for line in text.splitlines():
        fence = line.strip().startswith("```")
        if language is None and fence:
            language, lines = line.strip()[3:].strip(), []
        elif language is not None and fence:
            if language in languages:
                blocks.append("\n".join(lines) + "\n")
            language = None
        elif language is not None:
            lines.append(line)
    return blocks


def shell_commands(text: str) -> list[list[str]]:
    """The simple commands of the shell code blocks of a Markdown text (continuation lines joined,
    comments dropped, split at pipes, ``&&`` and ``;``), each as its words."""
    commands = []
    for block in code_blocks(text, SHELLS):
        for line in block.replace("\\\n", " ").splitlines():
            lexer = shlex.shlex(line, posix=True, punctuation_chars=True)
            lexer.whitespace_split = True
            try:
                tokens = list(lexer)
            except ValueError as e:  # an unclosed quote: the block is not shell
                raise AssertionError(f"not a shell line: {line!r}") from e
            words: list[str] = []
            for token in tokens + [";"]:
                if token in OPERATORS or set(token) <= set("|&;<>()"):
                    if words:
                        commands.append(words)
                    words = []
                else:
                    words.append(token)
    return commands


def madp_invocation(words: list[str]) -> list[str] | None:
    """The arguments given to ``madp`` (``madp …``, ``.venv/bin/madp …``, ``python -m madp.cli …``), or None."""
    for i, w in enumerate(words):
        if os.path.basename(w) == "madp":
            return words[i + 1:]
        if w == "-m" and i + 1 < len(words) and words[i + 1] == "madp.cli":
            return words[i + 2:]
    return None


def check_command_line(args: list[str]) -> list[str]:
    """What is wrong with ``madp ARGS`` (empty when every subcommand and ``--option`` exists)."""
    cmd = typer.main.get_command(app)
    path = ["madp"]
    problems = []
    rest = list(args)
    while hasattr(cmd, "commands") and rest and rest[0] in cmd.commands:
        path.append(rest[0])
        cmd = cmd.commands[rest.pop(0)]
    group_options = {o for p in getattr(cmd, "params", []) for o in getattr(p, "opts", [])}
    if hasattr(cmd, "commands") and rest and set(rest) <= group_options:  # a group's own option: madp --version
        return problems
    if hasattr(cmd, "commands") and not getattr(cmd, "invoke_without_command", False):
        problems.append(f"{' '.join(path)}: expected one of {sorted(cmd.commands)}, got {rest[:1]}")
        return problems
    known = {"--help"} | {o for p in cmd.params for o in [*getattr(p, "opts", []), *getattr(p, "secondary_opts", [])]}
    for word in rest:
        if word.startswith("--") and word != "--" and "…" not in word:
            option = word.split("=", 1)[0]
            if option not in known:
                problems.append(f"{' '.join(path)}: no option {option}")
    return problems


def documented_command_lines() -> list[tuple[str, list[str]]]:
    found = []
    for page in PAGES:
        for words in shell_commands(page.read_text(encoding="utf-8")):
            args = madp_invocation(words)
            if args is not None:
                found.append((str(page.relative_to(ROOT)), args))
    return found


def test_every_documented_command_line_exists_in_the_cli():
    lines = documented_command_lines()
    assert len(lines) > 30, "the pages' madp command lines were not found"
    assert {args[0] for _, args in lines if args} >= {"datagen", "train", "eval", "rollout", "dataset", "bench"}
    problems = [f"{page}: madp {' '.join(args)}: {p}" for page, args in lines for p in check_command_line(args)]
    assert not problems, "\n".join(problems)


def test_the_command_line_check_finds_what_does_not_exist():
    text = "```bash\nmadp eval --suite uniform --no-such-option 3   # a comment --nor-this\n" \
           "madp evaluate --suite x && .venv/bin/madp eval compare a b --baseline a\n" \
           "python -m madp.cli dataset\nmadp --version && madp --verbose\n```\n"
    found = [madp_invocation(w) for w in shell_commands(text)]
    commands = sorted(typer.main.get_command(app).commands)
    assert {"datagen", "dataset", "eval", "train"} <= set(commands)
    assert [check_command_line(a) for a in found] == [
        ["madp eval: no option --no-such-option"],
        [f"madp: expected one of {commands}, got ['evaluate']"],
        [],
        ["madp dataset: expected one of ['convert', 'import', 'info', 'merge', 'verify'], got []"],
        [],
        [f"madp: expected one of {commands}, got ['--verbose']"],
    ]


def _gen_cli():
    spec = importlib.util.spec_from_file_location("gen_cli", DOCS / "gen_cli.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_command_line_reference_is_what_the_app_says():
    gen = _gen_cli()
    assert gen.PAGE.read_text(encoding="utf-8") == gen.render(), "run python docs/gen_cli.py"


@pytest.mark.parametrize("example", sorted((DOCS / "extend").glob("*.py")), ids=lambda p: p.name)
def test_the_extension_guide_examples_run(example):
    assert f'--8<-- "extend/{example.name}"' in (DOCS / "guides" / "extend.md").read_text(encoding="utf-8")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    r = subprocess.run([sys.executable, str(example)], cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]


def test_the_readme_is_short():
    lines = (ROOT / "README.md").read_text(encoding="utf-8").splitlines()
    assert len(lines) <= 250
    assert [i + 1 for i, line in enumerate(lines) if len(line) > 120] == []
    assert lines[2] == "```bash"  # the two opening commands come first
    assert lines[3].startswith("bash scripts/quickstart.sh") and lines[4].startswith("bash .ci/run")


def test_no_page_source_or_test_names_a_work_item():
    """Say what a thing does, not which ticket brought it."""
    pattern = re.compile(r"issue ?[0-9]+", re.I)
    files = [ROOT / "README.md", *(p for d in ("madp", "tests", "docs", "scripts") for p in (ROOT / d).rglob("*")
                                   if p.is_file() and p.suffix in {".py", ".md", ".sh", ".toml", ".json", ".yml"})]
    hits = [f"{p.relative_to(ROOT)}:{i + 1}" for p in files
            for i, line in enumerate(p.read_text(encoding="utf-8", errors="replace").splitlines()) if pattern.search(line)]
    assert not hits, hits


# --- what a reader can follow ------------------------------------------------------------------------

#: Words that point at this project's internals, not at anything a reader has: the specification and
#: notes the project was built from, its tracker, and the machine it was developed on.
INTERNAL = re.compile(r"\bSPEC\b|design notes|\bthe issue\b|issue ?#?[0-9]+|this 2-core|the 2-core machine|"
                      r"\.\./shared|MADP_SHARED", re.I)
#: A file of the repository named in a page: a path under one of its folders, or a script's bare name.
FILE_NAME = re.compile(r"(?<![\w./\"-])((?:\.ci|scripts|tests|madp|docs|robot)/[\w./-]*\w|[\w-]+\.(?:py|sh))(?![\w/*-])")


def tracked_files() -> set[str]:
    files = {str(p.relative_to(ROOT)) for p in ROOT.rglob("*") if ".venv" not in p.parts and ".git" not in p.parts}
    return files | {str(Path(f).name) for f in files}


def dead_file_names(text: str, page: Path, files: set[str]) -> list[str]:
    """The repository paths and script names ``text`` (of ``page``) names that do not exist: paths are
    taken from the repository's root or the page's folder; a bare ``NAME.py``/``NAME.sh`` anywhere."""
    dead = []
    earlier = set(re.findall(r"git show [0-9a-f]{7,40}:(?:\S*/)?([\w.-]+)", text))  # a file git brings back
    text = re.sub(r"git show [0-9a-f]{7,40}:\S+", "", text)
    for m in FILE_NAME.finditer(text):
        name = m.group(1).rstrip(".")
        if "*" in name or "<" in name or "…" in name or re.search(r"-v\d+$", name):  # a pattern; a Gymnasium id
            continue
        here = str((page.parent / name).resolve().relative_to(ROOT)) if (page.parent / name).resolve().is_relative_to(ROOT) else ""
        if name not in files and here not in files and name not in earlier:
            dead.append(name)
    return dead


def test_no_page_names_what_a_reader_cannot_follow():
    """No page points at the project's internals (its specification, its tracker, its machine)."""
    hits = [f"{p.relative_to(ROOT)}:{i + 1}: {m.group()}" for p in PAGES
            for i, line in enumerate(p.read_text(encoding="utf-8").splitlines()) if (m := INTERNAL.search(line))]
    assert not hits, hits


def test_every_file_a_page_names_exists():
    files = tracked_files()
    dead = [f"{p.relative_to(ROOT)}: {name}" for p in PAGES for name in dead_file_names(p.read_text(encoding="utf-8"), p, files)]
    assert not dead, dead


def test_the_name_checks_find_what_does_not_exist():
    files = {"scripts/quickstart.sh", "quickstart.sh", "docs/guides/gpu.md", "gpu.md"}
    text = "Run `scripts/quickstart.sh`, then `python results_table.py`; see [a GPU](gpu.md) and `tests/gone.py`."
    assert dead_file_names(text, ROOT / "docs" / "guides" / "x.md", files) == ["results_table.py", "tests/gone.py"]
    work_item = "issue" + " 12"  # spelt apart: this file is checked for the words too
    assert [m.group() for line in ("SPEC §5 says", f"see {work_item}", "the EnvSpec of a suite")
            if (m := INTERNAL.search(line))] == ["SPEC", work_item]


GUIDES = sorted((DOCS / "guides").glob("*.md"))


@pytest.mark.parametrize("guide", GUIDES, ids=lambda p: p.name)
def test_every_guide_opens_with_a_runnable_block_and_holds_no_history(guide):
    """A guide is a how-to: its title, then a bash or python block (its first command runs on a fresh
    clone: tests/test_guides.py); then H2 sections; no dates (what changed when belongs to the reports
    and CHANGELOG.md)."""
    text = guide.read_text(encoding="utf-8")
    lines = text.splitlines()
    assert lines[0].startswith("# "), "a guide starts with its title"
    first = next(i for i, line in enumerate(lines) if line.startswith("```"))
    before = "\n".join(lines[1:first]).strip()
    assert lines[first].strip() in ("```bash", "```python"), f"{guide.name}: its first block is {lines[first]!r}"
    assert before == "", f"{guide.name}: prose before its first block"
    assert any(line.startswith("## ") for line in lines), f"{guide.name}: no H2 section"
    dates = [d for d in re.findall(r"\b20\d\d-\d\d-\d\d\b", re.sub(r"\]\([^)]*\)", "]", text))]
    assert not dates, f"{guide.name}: dated history {dates}; it belongs to a report or CHANGELOG.md"


@pytest.mark.parametrize("page", sorted((DOCS / "concepts").glob("*.md")), ids=lambda p: p.name)
def test_every_concept_page_is_in_sections(page):
    """A concept page is read by its parts: at least two H2 sections."""
    sections = [line for line in page.read_text(encoding="utf-8").splitlines() if line.startswith("## ")]
    assert len(sections) >= 2, f"{page.name}: {len(sections)} H2 sections"
