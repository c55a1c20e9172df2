"""The Coverage Control Library (``coverage-control`` 1.3.1, the ``madp[reference]`` extra) on madp's scenarios.

:func:`import_library` imports it on a CPU-only torch; :class:`LibraryEnv` builds the library's
``CoverageSystem`` for a :class:`~madp.sim.scenario.Scenario` under the conventions of the reference
vectors (SPEC §2): each feature passed as a bivariate normal of mass 2πσ²·peak truncated at the
scenario's σ count, the map scaled to a maximum of 1, the same world, sensor, local-map,
communication-radius, speed and time-step parameters. ``madp bench sim`` times it beside madp.

**CPU install.** ``coverage_control`` imports ``torchvision``, and PyPI's torchvision wheels are CUDA
builds: on a CPU-only torch their C++ extension (``torchvision/_C.so``, linked to ``libc10_cuda.so``)
does not load, and ``torchvision._meta_registrations`` then fails at import with ``RuntimeError:
operator torchvision::nms does not exist`` (pytorch/vision#9085). The library needs only
torchvision's pure-Python ``transforms.functional.resize``, so when the plain import fails that way,
:func:`import_library` imports torchvision again with its meta registrations (fake kernels for the
C++ detection ops, which are absent anyway) skipped. A CPU torchvision build, where one can be
installed, imports without the workaround and is used as it is.
"""

from __future__ import annotations

import contextlib
import importlib
import os
import sys
import tempfile
import types

import numpy as np

from .scenario import Scenario

_META = "torchvision._meta_registrations"
THREAD_LIMIT_ENV = "OMP_THREAD_LIMIT"
thread_limit_at_import: str | None = None
"""``OMP_THREAD_LIMIT`` when the library was imported: its OpenMP runtime reads it once, at load. Its
DecentralizedCVT asks for one thread per robot whatever ``OMP_NUM_THREADS`` says; only this caps it."""


def _import_torchvision():
    """Import torchvision; on a CPU torch with a CUDA torchvision wheel, skip its meta registrations."""
    try:
        return importlib.import_module("torchvision")
    except RuntimeError as e:
        if "torchvision::" not in str(e):
            raise
    # The failed import left its submodules behind (the extension module among them): start clean.
    for name in [m for m in sys.modules if m == "torchvision" or m.startswith("torchvision.")]:
        del sys.modules[name]
    sys.modules[_META] = types.ModuleType(_META, "skipped by madp.sim.reference: torchvision's C++ ops did not load")
    try:
        return importlib.import_module("torchvision")
    except BaseException:
        sys.modules.pop(_META, None)
        raise


def import_library(thread_limit: str | None = None):
    """The ``coverage_control`` module, or ImportError with the reason (not installed, or its imports fail).

    ``thread_limit``: ``OMP_THREAD_LIMIT`` for the OpenMP runtimes this import loads (the library's, and
    torch's if torch is not loaded yet), unless the environment sets one; the environment is restored
    afterwards, so processes started later do not inherit it. No effect once the library is imported."""
    if "coverage_control" in sys.modules:
        return sys.modules["coverage_control"]
    if importlib.util.find_spec("coverage_control") is None:
        raise ImportError("coverage_control is not installed (pip install 'madp[reference]', see docs/reports/benchmarks.md)")
    global thread_limit_at_import
    before = os.environ.get(THREAD_LIMIT_ENV)
    try:
        if thread_limit is not None and before is None:
            os.environ[THREAD_LIMIT_ENV] = thread_limit
        thread_limit_at_import = os.environ.get(THREAD_LIMIT_ENV)
        _import_torchvision()
        import coverage_control
        import coverage_control.algorithms  # noqa: F401
    except (ImportError, RuntimeError, OSError) as e:
        raise ImportError(f"coverage_control does not import ({type(e).__name__}: {e}); install madp[reference] "
                          "as docs/reports/benchmarks.md says") from e
    finally:
        if before is None:
            os.environ.pop(THREAD_LIMIT_ENV, None)
    return coverage_control


def library_available() -> tuple[bool, str]:
    """(True, version) if the library imports, else (False, the reason in one line)."""
    try:
        return True, import_library().__version__
    except ImportError as e:
        return False, str(e).splitlines()[0]


def library_parameters(scenario: Scenario):
    """The library's ``Parameters`` for ``scenario``'s :class:`~madp.sim.params.SimParams`."""
    cc = import_library()
    p = scenario.params
    lp = cc.Parameters()
    lp.pNumRobots = len(scenario.robots_m)
    lp.pNumGaussianFeatures = len(scenario.features)
    lp.pWorldMapSize = p.world_size
    lp.pRobotMapSize = p.world_size
    lp.pResolution = 1.0
    lp.pLocalMapSize = p.local_map_size
    lp.pSensorSize = p.sensor_size
    lp.pCommunicationRange = p.comm_radius_m
    lp.pMaxRobotSpeed = p.max_speed_mps
    lp.pTimeStep = p.dt_s
    lp.pTruncationBND = p.truncation_sigmas
    lp.pNorm = 1.0
    lp.pCheckOscillations = p.check_oscillations
    return lp


@contextlib.contextmanager
def _quiet_cuda_probe():
    """Drop the two lines the library's C++ writes to stderr when it finds no CUDA device (WorldIDF's
    constructor looks for one); anything else it writes there is passed on."""
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), 2)
        try:
            yield
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            rest = [ln for ln in tmp.read().decode(errors="replace").splitlines()
                    if ln.strip() and "CUDA" not in ln]
            if rest:
                print("\n".join(rest), file=sys.stderr)


class LibraryEnv:
    """One episode of ``scenario`` in the library: the four operations ``madp bench sim`` times.

    ``step_clairvoyant`` / ``step_dcvt`` are what the library's ``ControllerCVT.step`` does without its
    objective (compute actions, get them, ``StepActions``); ``cost`` is ``GetObjectiveValue`` (J);
    ``observations`` is ``CoverageEnvUtils.get_maps(…, obs_size, use_comm_map=True)``, the LPAC input
    [N, 4, 32, 32].
    """

    def __init__(self, scenario: Scenario):
        cc = import_library()
        if scenario.params.history_size != 20:
            raise ValueError("the library's position history is fixed at 20 entries")
        self.cc, self.scenario = cc, scenario
        self.params = library_parameters(scenario)
        with _quiet_cuda_probe():
            self.world_idf = cc.WorldIDF(self.params)
        for mx, my, sigma, peak in np.asarray(scenario.features, dtype=np.float64).reshape(-1, 4):
            mass = 2.0 * np.pi * sigma * sigma * peak
            self.world_idf.AddNormalDistribution(cc.BivariateNormalDistribution(np.array([mx, my]), sigma, mass))
        self.world_idf.GenerateMapCPU()  # the CPU path, as the reference vectors were made
        self.reset()

    def reset(self) -> None:
        """A fresh ``CoverageSystem`` at the scenario's start positions, with both CVT controllers."""
        from coverage_control.algorithms import ClairvoyantCVT, DecentralizedCVT

        start = self.cc.PointVector([np.asarray(r, dtype=np.float64) for r in self.scenario.robots_m])
        self.system = self.cc.CoverageSystem(self.params, self.world_idf, start)
        self.clairvoyant = ClairvoyantCVT(self.params, self.system)
        self.dcvt = DecentralizedCVT(self.params, self.system)

    def _step(self, alg) -> None:
        alg.ComputeActions()
        if self.system.StepActions(alg.GetActions()):
            raise RuntimeError("coverage_control: StepActions reported an error")

    def step_clairvoyant(self) -> None:
        self._step(self.clairvoyant)

    def step_dcvt(self) -> None:
        self._step(self.dcvt)

    def cost(self) -> float:
        return float(self.system.GetObjectiveValue())

    def observations(self):
        return self.cc.CoverageEnvUtils.get_maps(self.system, self.params, self.scenario.params.obs_size, True)

    @property
    def positions_m(self) -> np.ndarray:
        return np.array([np.asarray(p) for p in self.system.GetRobotPositions()], dtype=np.float64).reshape(-1, 2)

    @property
    def world_map(self) -> np.ndarray:
        return np.asarray(self.system.GetWorldMap())
