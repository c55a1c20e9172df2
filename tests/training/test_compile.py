"""``madp train --compile``: MADP through torch.compile trains what eager trains (to float rounding:
inductor fuses element-wise ops, so bits may differ), resumes exactly, and LPAC-K3 refuses it."""

import pytest

from madp.training import resolve, train
from tests.conftest import tiny_dataset
from tests.test_reliability_errors import cli
from tests.training.test_training import losses


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    return tiny_dataset(tmp_path_factory, "compile-data")


def test_lpac_refuses_compile_in_one_line(dataset):
    code, err = cli("train", "--model", "lpac", "--data", dataset, "--compile")
    assert code == 2 and "--compile" in err and len(err.strip().splitlines()) == 1


@pytest.mark.slow
def test_compiled_training_matches_eager_and_resumes_exactly(dataset, tmp_path):
    """Compiling takes a minute or more, so this runs with ``-m slow``. The compiled run's losses equal
    the eager run's to 1e-4 (same data, noise and init), and a compiled run stopped after 5 steps and
    resumed logs exactly the losses of an unbroken compiled run."""
    kw = dict(data=str(dataset), epochs=1, batch_size=8, num_workers=0, log_every=1, val_samples=16,
              checkpoint_every=3, seed=7, max_steps_per_epoch=8)
    train(resolve("madp", "cpu", out=str(tmp_path / "eager"), **kw), progress=False)
    train(resolve("madp", "cpu", out=str(tmp_path / "full"), compile=True, **kw), progress=False)
    eager, compiled = losses(tmp_path / "eager"), losses(tmp_path / "full")
    assert [s for s, _ in eager[0]] == [s for s, _ in compiled[0]]
    assert compiled[0][-1][1] == pytest.approx(eager[0][-1][1], rel=1e-4)
    assert compiled[1] == pytest.approx(eager[1], rel=1e-4)
    train(resolve("madp", "cpu", out=str(tmp_path / "part"), compile=True, stop_after_steps=5, **kw), progress=False)
    train(resolve("madp", "cpu", out=str(tmp_path / "part"), compile=True, **kw), resume=True, progress=False)
    assert losses(tmp_path / "part") == compiled
