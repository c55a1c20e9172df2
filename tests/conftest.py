"""Shared test fixtures, and where the reference data lives.

The reference data ships inside the repository, so a clone anywhere runs every test: the Coverage
Control Library's reference vectors in ``tests/data/vectors`` (``tests/data/README.md`` says how they
were made) and the 40 cities' traffic-signal files that madp itself ships
(``madp/cities/data``). Use the ``vectors_dir`` / ``cities_dir`` fixtures (or the ``VECTORS`` /
``CITIES`` paths), never a path of your own; a missing directory fails the test that needs it, naming it.
"""

import contextlib
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as the CLI does: small products, no BLAS threads
# One torch (OpenMP) thread per process, here and in the commands the tests start (they inherit it): the
# tests' models are tiny and pytest-xdist already runs a worker per core; with more threads than cores
# OpenMP's hand-offs make small ops many times slower (a 2-core CI: 4 workers x 2 threads).
os.environ.setdefault("OMP_NUM_THREADS", "1")
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
DATA = REPO / "tests" / "data"
VECTORS = DATA / "vectors"
CITIES = REPO / "madp" / "cities" / "data"  # madp.eval.suites.default_cities_dir()


@contextlib.contextmanager
def one_torch_thread():
    """Run the block with one torch intra-op thread (as ``--threads 1`` and the commands the tests start
    run), restoring the previous count after it."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(before)


def in_ci() -> bool:
    """True when the ``CI`` environment variable is set (to anything but empty, 0 or false)."""
    return os.environ.get("CI", "").strip().lower() not in ("", "0", "false", "no")


def require_dir(path: Path, what: str) -> Path:
    """``path`` if it is a directory; otherwise fail the test, naming it (the data ships with the repository)."""
    if not path.is_dir():
        pytest.fail(f"{what} not found: directory {path} is missing from this checkout", pytrace=False)
    return path


def pytest_collection_modifyitems(config, items):
    """Tests marked ``cuda`` live in ``test_cuda*.py`` files (``scripts/gpu_paper.sh`` runs exactly
    those, with ``-m cuda``) and are skipped, with the reason, where torch sees no CUDA GPU."""
    cuda = [item for item in items if item.get_closest_marker("cuda")]
    misplaced = [item.nodeid for item in cuda if not item.path.name.startswith("test_cuda")]
    if misplaced:
        raise pytest.UsageError(f"tests marked cuda must live in test_cuda*.py files: {misplaced}")
    if not cuda:
        return
    import torch

    if not torch.cuda.is_available():
        skip = pytest.mark.skip(reason=f"needs a CUDA GPU: torch.cuda.is_available() is False (torch {torch.__version__})")
        for item in cuda:
            item.add_marker(skip)


@pytest.fixture(scope="session")
def vectors_dir() -> Path:
    return require_dir(VECTORS, "reference vectors")


@pytest.fixture(scope="session")
def cities_dir() -> Path:
    return require_dir(CITIES, "city files")


def run_script(script: Path, *args, timeout: float = 600):
    """``bash script args…`` with one OpenMP thread: the finished process (stdout and stderr captured)."""
    import subprocess

    env = dict(os.environ, OMP_NUM_THREADS="1")
    return subprocess.run(["bash", str(script), *map(str, args)], capture_output=True, text=True, env=env,
                          timeout=timeout)


def script_results(tmp_path_factory, script: Path, *args) -> Path:
    """A fresh directory in which ``bash script OUT --work WORK args…`` has succeeded (else the ends
    of its output are the failure); OUT and WORK are its ``out`` and ``work`` folders."""
    root = tmp_path_factory.mktemp(script.stem)
    r = run_script(script, root / "out", "--work", root / "work", *args)
    assert r.returncode == 0, (r.stdout[-3000:], r.stderr[-3000:])
    return root


def returned_files(out: Path) -> list[str]:
    """The sorted names of what a GPU-machine script left in ``out``, checked against what the
    machine's return channel carries back: at most 8 plain files of at most 16 MiB each."""
    files = sorted(p.name for p in out.iterdir())
    assert len(files) <= 8 and all((out / f).is_file() and (out / f).stat().st_size <= 16 << 20 for f in files)
    return files


def tiny_dataset(tmp_path_factory, name: str, workers: int = 1) -> Path:
    """The small dataset the training, kill and error tests share: 160 samples of 4 robots and 4
    features on a 256 m world, seed 1, shards of 16 (the bytes do not depend on ``workers``)."""
    from madp.datagen import DatagenConfig, run_datagen
    from madp.sim import SimParams

    root = tmp_path_factory.mktemp(name)
    cfg = DatagenConfig(160, seed=1, samples_per_shard=16, params=SimParams(world_size=256, num_robots=4, num_features=4))
    run_datagen(cfg, root, workers=workers, progress=False)
    return root
