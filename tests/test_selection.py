"""The selection rules' records (madp/selection.py) and everything made from them: the command line's
``--select`` help, the documentation's table of rules, the summary's prose; the robot imports them
without torch; no other module of madp lists rule names."""

from __future__ import annotations

import ast
import re
import subprocess
import sys
from pathlib import Path

import pytest

from madp.selection import DEFAULT_RULE, NEEDS, RULES, SEES, check_rule, rule_names, rules_table, select_help

ROOT = Path(__file__).resolve().parents[1]
MADP = ROOT / "madp"


def test_each_record_is_complete_and_the_bounds_are_marked():
    assert DEFAULT_RULE in RULES and not RULES[DEFAULT_RULE].bound and not RULES[DEFAULT_RULE].prior
    for name, r in RULES.items():
        assert r.name == name and re.fullmatch(r"[a-z][a-z_]*", name)
        assert r.sees in SEES and r.help and "\n" not in r.help and len(r.help) <= 160
        assert r.bound == name.startswith("oracle"), name  # a bound is named as one
        assert r.ranks == (r.sees in ("own map", "true map"))
        assert not (r.prior and r.bound)
    assert rule_names(sees=("samples",)) == ("none",)


@pytest.mark.parametrize("command", [("eval",), ("rollout",), ("export",)])
def test_the_select_help_is_made_from_the_records(command):
    import typer

    from madp.cli import app

    cmd = typer.main.get_command(app)
    for part in command:
        cmd = cmd.commands[part]
    option = next(p for p in cmd.params if p.name == "select")
    assert option.help == select_help() and len(option.help) <= 600
    for name, r in RULES.items():
        assert name in option.help
        assert (f"{name} (an upper bound" in option.help) == r.bound


def test_the_documentations_table_of_rules_is_the_records():
    page = (ROOT / "docs" / "concepts" / "sampling.md").read_text(encoding="utf-8")
    block = page.split("<!-- rules: generated from madp.selection.RULES -->\n")[1].split("\n<!-- /rules -->")[0]
    assert block == rules_table(), "docs/concepts/sampling.md's table of rules: paste madp.selection.rules_table()"


def test_the_summary_prose_names_each_rule_by_its_record():
    from madp.eval.tables import select_prose

    for name, r in RULES.items():
        prose = select_prose(name, 4)
        assert (prose == "") == (r.sees == "samples")
        if prose:
            assert r.help in prose and ("upper bound" in prose) == r.bound
    assert select_prose("retired_rule", 4) == ""  # a kept result of a retired rule still reads


def test_a_bad_rule_or_k_is_one_setting_error():
    from madp.errors import SettingError

    for name, k, setting in (("vote", 4, "select"), ("none", 4, "select/candidates"),
                             (DEFAULT_RULE, 1, "select/candidates"), (DEFAULT_RULE, 0, "candidates")):
        with pytest.raises(SettingError) as e:
            check_rule(name, k)
        assert e.value.setting == setting and "\n" not in str(e.value)


def test_a_rule_falls_back_only_where_its_network_is_missing():
    """A fallback is a controller that reads no learned network; the default runs on any policy file
    (its fallback on one without the network it needs), a rule without a fallback stays itself (and
    is refused where its network is read); the settings keep K and the rest."""
    from madp.policies import SamplingSettings
    from madp.selection import runnable

    for name, r in RULES.items():
        if r.fallback:
            assert r.needs and not RULES[r.fallback].needs and not RULES[r.fallback].bound, name
        for carried in ((), tuple(NEEDS)):
            expect = r.fallback if r.fallback and r.needs and r.needs not in carried else name
            assert runnable(name, carried) == expect
    assert not RULES[runnable(DEFAULT_RULE, ())].needs
    k8 = SamplingSettings.of(candidates=8)
    assert k8.fitted(tuple(NEEDS)) is k8
    fitted = k8.fitted(())
    assert (fitted.select, fitted.candidates) == (runnable(DEFAULT_RULE, ()), 8)


def test_the_records_import_without_torch_or_the_simulator():
    code = "import sys, madp.selection; print(sorted(m for m in ('torch', 'madp.sim', 'numba') if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


@pytest.mark.parametrize("path", sorted(MADP.rglob("*.py")), ids=lambda p: str(p.relative_to(ROOT)))
def test_rule_names_are_listed_only_in_the_records(path):
    """No literal tuple, list, set or dict outside ``madp/selection.py`` names two rules, and the name of
    the default appears as a string in no other module: every list of rules derives from the records."""
    if path == MADP / "selection.py":
        return
    tree = ast.parse(path.read_text(encoding="utf-8"))
    for node in ast.walk(tree):
        items = node.keys if isinstance(node, ast.Dict) else getattr(node, "elts", None)
        if isinstance(node, (ast.Tuple, ast.List, ast.Set, ast.Dict)) and items:
            named = {x.value for x in items if isinstance(x, ast.Constant) and x.value in RULES}
            assert len(named) < 2, f"{path.relative_to(ROOT)}:{node.lineno} lists rules {sorted(named)}"
        if _names_the_default_rule(node):
            pytest.fail(f"{path.relative_to(ROOT)}:{node.lineno} names the rule {DEFAULT_RULE!r}: use DEFAULT_RULE or a record")


def _names_the_default_rule(node: ast.AST) -> bool:
    """The default rule's name as a string, or, where that name is also a learned network's (a key of
    NEEDS or its weights' key), as a rule: a ``select=``/``rule=`` keyword or a comparison with
    something named select or rule."""
    is_default = lambda n: isinstance(n, ast.Constant) and n.value == DEFAULT_RULE  # noqa: E731
    if DEFAULT_RULE not in NEEDS and DEFAULT_RULE not in {n.key for n in NEEDS.values()}:
        return is_default(node)
    if isinstance(node, ast.keyword):
        return node.arg in ("select", "rule") and is_default(node.value)
    if isinstance(node, ast.Compare):
        text = ast.unparse(node)
        return any(is_default(n) for n in (node.left, *node.comparators)) and ("select" in text or "rule" in text)
    return False
