"""The one sampling spec (madp/sampling.py): ``--sampling NAME=VALUE,...`` parsed once, the same on every
command that samples a policy, its single flags the same names everywhere, and the sampling and the
noise source written into the result files."""

from __future__ import annotations

import json

import pytest
import typer

from madp.cli import app
from madp.errors import SettingError
from madp.policies import SamplingSettings
from madp.sampling import KEYS, merge_sampling, parse_sampling, spec_text
from tests.test_reliability_errors import assert_one_line, cli

#: Every command that samples a policy, as the command line names it.
SAMPLING_COMMANDS = (("eval",), ("rollout",), ("datagen",), ("export",), ("swarm",))


def test_the_spec_parses_into_the_settings_and_back():
    spec = "sampler=dpm++,steps=3,k=4,rule=critic,frame=d4,precision=fp32"
    given = parse_sampling(spec)
    assert given == {"sampler": "dpm++", "sampling_steps": 3, "candidates": 4, "select": "critic", "frame": "d4",
                     "precision": "fp32"}
    assert SamplingSettings.of(**given) == SamplingSettings()  # the defaults, spelled out
    assert spec_text(SamplingSettings().as_dict()) == spec + ",eta=0.0,fixed_noise=false"
    assert parse_sampling(spec_text(SamplingSettings().as_dict())) == SamplingSettings().as_dict()
    assert parse_sampling(None) == parse_sampling("") == {}
    assert parse_sampling("fixed_noise=true, eta=0.5") == {"fixed_noise": True, "eta": 0.5}


@pytest.mark.parametrize("text,needle", [
    ("k", "expected NAME=VALUE"), ("K=4", "expected NAME=VALUE"), ("k=four", "k: expected int"),
    ("k=4,k=8", "k is given twice"), ("fixed_noise=maybe", "fixed_noise: expected bool"),
])
def test_a_bad_spec_is_one_setting_error(text, needle):
    with pytest.raises(SettingError) as e:
        parse_sampling(text)
    assert e.value.setting == "sampling" and needle in str(e.value) and "\n" not in str(e.value)


def test_a_flag_may_add_to_the_spec_but_not_say_otherwise():
    assert merge_sampling("k=8", select="explore", candidates=None) == {"candidates": 8, "select": "explore"}
    assert merge_sampling("k=8", candidates=8) == {"candidates": 8}
    with pytest.raises(SettingError, match="k=8 says otherwise than --candidates 4"):
        merge_sampling("k=8", candidates=4)


@pytest.mark.parametrize("command", SAMPLING_COMMANDS, ids=lambda c: " ".join(c))
def test_every_sampling_command_takes_the_spec_and_the_same_single_flags(command):
    cmd = typer.main.get_command(app)
    for part in command:
        cmd = cmd.commands[part]
    flags = {p.opts[0]: p for p in cmd.params}
    assert "--sampling" in flags and all(k in flags["--sampling"].help for k in KEYS)
    single = {"--select", "--candidates", "--sampling-steps", "--sampler", "--frame", "--precision"} & set(flags)
    for f in single:  # a single flag that a spec key also sets has one name everywhere
        assert f.lstrip("-").replace("-", "_") in {s for _, s in KEYS.values()}


def test_eval_refuses_a_spec_and_a_flag_that_disagree_in_one_line(tmp_path):
    assert_one_line(*cli("eval", "--sampling", "rule=explore", "--select", "oracle", "--out", tmp_path),
                    "--sampling: rule=explore says otherwise than --select oracle")
    assert_one_line(*cli("eval", "--sampling", "k=0", "--out", tmp_path), "--candidates")
    assert_one_line(*cli("datagen", "--n", 10, "--sampling", "rule=explore", "--out", tmp_path / "d"),
                    "--sampling: only meaningful with a policy")


def test_rollout_writes_its_sampling_and_noise_source(tmp_path):
    sc = tmp_path / "s.json"
    sc.write_text('{"features": [{"mean": [100, 100], "sigma": 40, "peak": 1.0}], "robots": [[90, 90], [120, 110], [300, 300]], "seed": 3}')
    out = tmp_path / "r.json"
    code, err = cli("rollout", "--scenario", sc, "--controller", "madp", "--steps", 2, "--out", out,
                    "--sampling", "k=2,steps=2,frame=world")
    assert code == 0, err
    doc = json.loads(out.read_text())["sampling"]
    assert (doc["candidates"], doc["sampling_steps"], doc["frame"], doc["noise"], doc["runtime"]) == (2, 2, "world", "torch", "torch")
    assert parse_sampling(doc["spec"])["candidates"] == 2
    code, err = cli("rollout", "--scenario", sc, "--controller", "dcvt", "--steps", 1, "--out", out, "--sampling", "k=2")
    assert_one_line(code, err, "--sampling: the dcvt controller does not sample")
