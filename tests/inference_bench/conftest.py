"""The untrained policy files of the evaluation tests (the plumbing, not the skill, is under test)."""

from tests.eval.conftest import checkpoints  # noqa: F401  (a fixture)
