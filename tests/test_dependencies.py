"""The package runs on its declared dependencies: no module of it imports a test-only package (scipy, hypothesis,
pytest), so `pip install seaice_jax` without the test extra gives every command."""

import pkgutil
import subprocess
import sys

import numpy as np
from scipy.ndimage import binary_erosion

import seaice_jax
from seaice_jax.workflows.sequence_adjust import static_surface_interior

TEST_ONLY = ("scipy", "hypothesis", "pytest")


def test_every_module_imports_without_the_test_only_packages():
    modules = [m.name for m in pkgutil.walk_packages(seaice_jax.__path__, "seaice_jax.")]
    script = ("import sys, importlib\n"
              f"for blocked in {TEST_ONLY!r}:\n"
              "    sys.modules[blocked] = None\n"
              f"for name in {modules!r}:\n"
              "    importlib.import_module(name)\n")
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    assert len(modules) > 50


def test_the_static_surfaces_interior_is_scipys_binary_erosion():
    rng = np.random.default_rng(7)
    for shape, fraction in (((37, 23), 0.3), ((5, 64), 0.1), ((1, 9), 0.0), ((40, 40), 0.6)):
        mask = rng.random(shape) > fraction
        np.testing.assert_array_equal(static_surface_interior(mask), binary_erosion(mask))
