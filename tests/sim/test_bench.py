"""``madp bench sim``: the table it prints (structure, finite positive figures; never a speed), and the
Coverage Control Library adapter it times (the library on madp's scenario reproduces the reference vectors).

The library is the optional ``madp[reference]`` extra: its tests skip without it, and fail in CI, whose
``.ci/run`` installs it.
"""

import contextlib
import io
import json
import math

import numpy as np
import pytest

from madp.cli import main
from madp.sim.bench import OPERATIONS
from madp.sim.reference import library_available

from tests.conftest import in_ci


@pytest.fixture
def library():
    # Imported here, not at collection: every xdist worker collects this file.
    ok, why_not = library_available()
    if not ok:
        msg = f"coverage_control not importable: {why_not}"
        if in_ci():
            pytest.fail(f"{msg}; .ci/run installs madp[reference]", pytrace=False)
        pytest.skip(msg)


def bench(tmp_path, *flags):
    """Run the cheapest ``madp bench sim`` in this process: (printed lines, the --out JSON)."""
    out = tmp_path / "bench.json"
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        main(["bench", "sim", "--scenarios", "1", "--steps", "10", "--out", str(out), *flags])
    return buf.getvalue().splitlines(), json.loads(out.read_text())


def numbers(line: str, op: str) -> list[float]:
    assert line.split()[0] == op
    return [float(v.rstrip("x")) for v in line.split()[1:]]


def test_without_the_library_madp_figures_alone(tmp_path):
    lines, res = bench(tmp_path, "--no-library")
    assert len(lines) == 3 + len(OPERATIONS), lines
    assert lines[0].startswith("1 scenarios x 10 steps") and "medians of 10 calls" in lines[0]
    assert lines[1].startswith("Coverage Control Library not measured:")
    assert lines[2].split() == ["what", "madp", "ms", "p90", "ms"]
    for line, op in zip(lines[3:], OPERATIONS):
        med, p90 = numbers(line, op)
        assert 0 < med <= p90 and math.isfinite(p90)
    assert res["library"] is None and res["steps"] == 10 and res["scenarios"] == 1
    for op in OPERATIONS:
        r = res["operations"][op]
        assert r["samples"] == 10 and r["library_ms"] is None and r["ratio"] is None


def test_with_the_library_side_by_side(tmp_path, library):
    lines, res = bench(tmp_path, "--library")
    assert len(lines) == 2 + len(OPERATIONS), lines
    assert f"interleaved with coverage_control {res['library']} (" in lines[0]
    assert lines[1].split() == ["what", "library", "ms", "madp", "ms", "ratio"]
    for line, op in zip(lines[2:], OPERATIONS):
        lib_ms, madp_ms, ratio = numbers(line, op)
        assert lib_ms > 0 and madp_ms > 0 and ratio > 0
        r = res["operations"][op]
        assert r["samples"] == 10
        assert math.isfinite(r["ratio"]) and r["ratio"] > 0
        assert r["ratio"] == pytest.approx(r["library_ms"] / r["madp_ms"])


def test_library_adapter_reproduces_the_reference_vectors(vectors_dir, library):
    """The bench's mapping of a madp scenario to the library's (features as 2πσ²·peak masses, the
    parameters) is the one the reference vectors were made with: the library's own figures come back."""
    from madp.sim.reference import LibraryEnv
    from tests.sim.test_vectors import load

    d, meta, sc = load("uniform_seed1001")
    lib = LibraryEnv(sc)
    assert lib.cost() == pytest.approx(meta["objective0"], rel=1e-12)
    np.testing.assert_array_equal(lib.observations().numpy(), d["lpac_maps0"])
    for _ in range(5):
        lib.step_clairvoyant()
    np.testing.assert_allclose(lib.positions_m, d["clairvoyant_positions_step5"], rtol=0, atol=1e-9)
    lib.reset()
    lib.step_dcvt()
    np.testing.assert_allclose(lib.positions_m, d["dcvt_positions_step1"], rtol=0, atol=1e-9)


def test_library_flag_without_the_library_is_one_line(monkeypatch, capsys):
    import madp.sim.reference as ref

    def missing(thread_limit=None):
        raise ImportError("coverage_control is not installed")

    monkeypatch.setattr(ref, "import_library", missing)
    with pytest.raises(SystemExit) as e:
        main(["bench", "sim", "--scenarios", "1", "--steps", "10", "--library"])
    err = capsys.readouterr().err.strip().splitlines()
    assert e.value.code == 2 and len(err) == 1 and "--library" in err[0] and "not installed" in err[0]
