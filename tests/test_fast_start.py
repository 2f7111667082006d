"""Fast for the person at the terminal: ``seaice --help`` loads no JAX, compilations are kept between runs (JAX's
persistent cache) and, within one process, a second fit of the same structure compiles nothing."""

import os
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.monitoring import register_event_duration_secs_listener, unregister_event_duration_listener

from seaice_jax._compilation_cache import default_cache_folder
from seaice_jax.adjust.orbit.fit import fit_scan_model
from seaice_jax.cli import CACHE_VARIABLE, build_parser
from seaice_jax.simulate.satellite import noaa_image, simulate_control_points

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
BACKEND_COMPILE_EVENT = "/jax/core/compile/backend_compile_duration"
"""The event JAX records for every executable it builds (compiled, or read from the persistent cache)."""


class CompileCounter:
    """Names of the functions XLA compiles while the context is open."""

    def __enter__(self):
        self.names = []
        register_event_duration_secs_listener(self._record)
        return self

    def _record(self, event: str, duration_secs: float, **metadata: str | int):
        if event == BACKEND_COMPILE_EVENT:
            self.names.append(metadata.get("fun_name"))

    def __exit__(self, *exc):
        unregister_event_duration_listener(self._record)


def _python(script: str, **environment) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300,
                          env={**os.environ, "JAX_PLATFORMS": "cpu", **environment})


@pytest.mark.parametrize("argument", ["--help", "--version"])
def test_help_and_version_do_not_import_jax(argument):
    script = ("import sys\nfrom seaice_jax.cli import main\n"
              f"try:\n    main([{argument!r}])\nexcept SystemExit as stop:\n    assert stop.code == 0, stop.code\n"
              "heavy = [m for m in ('jax', 'jaxlib', 'cv2', 'matplotlib') if m in sys.modules]\n"
              "assert not heavy, heavy\n")
    result = _python(script)
    assert result.returncode == 0, result.stderr[-2000:]
    assert ("usage: seaice" if argument == "--help" else "seaice_jax 0.1.0") in result.stdout


def test_importing_the_package_first_still_gives_float64():
    """The lazy package: JAX imported after ``import seaice_jax``, or before it, computes in float64."""
    after = _python("import seaice_jax, jax.numpy as jnp\nassert jnp.ones(1).dtype == jnp.float64\n"
                    "assert seaice_jax.geodetic_to_ecef(0.5, 0.1, 0.0)[0].dtype == jnp.float64\n")
    before = _python("import jax, jax.numpy as jnp\nimport seaice_jax\nassert jnp.ones(1).dtype == jnp.float64\n")
    assert after.returncode == 0, after.stderr[-2000:]
    assert before.returncode == 0, before.stderr[-2000:]


def test_seaice_code_runs_in_float64_even_when_the_caller_asks_for_float32():
    """A subpackage imports ``seaice_jax._config``: x64 is on before any of its code, whatever the environment."""
    result = _python("import jax.numpy as jnp\nfrom seaice_jax.geometry.earth import geodetic_to_ecef\n"
                     "assert jnp.ones(1).dtype == jnp.float64\n", JAX_ENABLE_X64="0")
    assert result.returncode == 0, result.stderr[-2000:]


def test_compile_cache_folder_follows_the_environment(monkeypatch, tmp_path):
    monkeypatch.delenv(CACHE_VARIABLE, raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert default_cache_folder() == tmp_path / "xdg" / "seaice_jax" / "jax"
    monkeypatch.setenv(CACHE_VARIABLE, str(tmp_path / "mine"))
    assert default_cache_folder() == tmp_path / "mine"
    monkeypatch.setenv(CACHE_VARIABLE, "")
    assert default_cache_folder() is None
    assert build_parser().parse_args(["--no-compile-cache", "demo"]).compile_cache is False
    assert build_parser().parse_args(["demo"]).compile_cache is True


def _cache_entries(folder: Path) -> set[str]:
    return {p.name for p in folder.iterdir()} if folder.exists() else set()


@pytest.mark.slow
def test_a_second_rectify_run_reuses_the_first_runs_compilations(tmp_path):
    """Every compilation of the first run lands in the cache (none too short to keep); the second run adds no
    entry, i.e. it compiled nothing."""
    cache = tmp_path / "cache"
    command = [sys.executable, "-m", "seaice_jax.cli", "rectify", str(EXAMPLES / "figure_3_3.csv"), "--satellite",
               "NOAA-7", "--altitude", "0", "--earth-day", "1440", "--direction", "south"]
    environment = {**os.environ, "JAX_PLATFORMS": "cpu", CACHE_VARIABLE: str(cache)}
    outputs = []
    for run in range(2):
        result = subprocess.run(command, capture_output=True, text=True, timeout=300, env=environment)
        assert result.returncode == 0, result.stderr[-2000:]
        outputs.append(result.stdout)
        if run == 0:
            first = _cache_entries(cache)
    assert len(first) > 10  # the fit's solver, the initial guess, the report's computations
    assert _cache_entries(cache) == first
    assert outputs[0] == outputs[1]


def test_the_compile_counter_sees_a_compilation():
    """The counter used below is not blind."""
    with CompileCounter() as counter:
        jax.jit(lambda x: jnp.sin(x) * 3.25 + 1.0)(jnp.arange(3.0))
    assert counter.names


@pytest.mark.parametrize("count", [9, 13])
def test_a_second_fit_with_as_many_control_points_compiles_nothing(count):
    """Within one process, a second ``fit_scan_model`` with as many control points, or another number of them in the
    same bucket of rows (9-16: the fit pads them), other points and other noise, compiles nothing; both fits recover
    the simulated image."""
    truth = noaa_image("south")
    rng = np.random.default_rng(18)
    first, second = (simulate_control_points(truth, n, rng, 500.0)[0] for n in (9, count))
    assert not np.allclose(np.asarray(first.pixel)[:9], np.asarray(second.pixel)[:9])
    fit_scan_model(first, truth.orbit, direction="south", n_pixels=truth.n_pixels, n_scans=truth.n_scans)
    with CompileCounter() as counter:
        fit = fit_scan_model(second, truth.orbit, direction="south", n_pixels=truth.n_pixels, n_scans=truth.n_scans)
    assert counter.names == []
    assert float(fit.model.ascending_node) == pytest.approx(float(truth.ascending_node), abs=np.radians(0.05))
    assert fit.rms_km < 1.5


def test_a_northbound_fit_after_a_southbound_one_compiles_nothing():
    """Both directions are one southbound problem inside the fit (and one compiled forward model): after a
    southbound fit, a northbound fit of another image with as many control points compiles nothing."""
    rng = np.random.default_rng(181)
    south = simulate_control_points(noaa_image("south"), 6, rng, 500.0)[0]
    truth = noaa_image("north")
    north = simulate_control_points(truth, 6, rng, 500.0)[0]
    first = fit_scan_model(south, truth.orbit, direction="south", n_pixels=truth.n_pixels, n_scans=truth.n_scans)
    _ = first.rms_km, first.dlon_arcmin, first.flagged_w_test()
    with CompileCounter() as counter:
        fit = fit_scan_model(north, truth.orbit, direction="north", n_pixels=truth.n_pixels, n_scans=truth.n_scans)
        _ = fit.rms_km, fit.dlon_arcmin, fit.flagged_w_test()
    assert counter.names == []
    assert float(fit.model.ascending_node) == pytest.approx(float(truth.ascending_node), abs=np.radians(0.05))
    assert fit.rms_km < 1.5
