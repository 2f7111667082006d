"""Monte Carlo over devices (issue 17): realizations sharded over two host devices equal the unsharded ones, bit
for bit for a batched linear solve, to rounding for the Gauss-Newton scan-model fit. (A file of its own: its
subprocess compiles the vmapped fit twice, ~22 s CPU, which made tests/test_archive.py the suite's longest file.)"""

import os
import subprocess
import sys

import numpy as np
import pytest

_SHARDED = """
import sys
import jax, jax.numpy as jnp, numpy as np
from seaice_jax import _config
from seaice_jax.adjust.orbit.fit import orbit_solver
from seaice_jax.adjust.engine.sharding import sharded_vmap
from seaice_jax.geometry.scan import SCAN_UNKNOWNS
from seaice_jax.simulate.satellite import overlapping_pair
assert jax.local_device_count() == 2, jax.devices()

def normal_solution(seed, scale):  # one linear least-squares realization (batched LAPACK under vmap)
    design = jax.random.normal(jax.random.key(seed), (7, 3)) * scale
    return jnp.linalg.solve(design.T @ design, design.T @ jnp.arange(7.0))

seeds = jnp.arange(9)  # padded to 10 over the two devices
linear = np.stack([np.asarray(jax.vmap(normal_solution, in_axes=(0, None))(seeds, 2.0)),
                   np.asarray(sharded_vmap(normal_solution, in_axes=(0, None))(seeds, 2.0))])
split = [shard.data.shape for shard in sharded_vmap(normal_solution, in_axes=(0, None))(
    jnp.arange(10), 2.0).addressable_shards]

# a Monte Carlo of the Gauss-Newton scan-model fit: noisy known positions, one fit per realization
rng = np.random.default_rng(12)
(first, _), (truth, _) = overlapping_pair(rng)
primary = first.primary
solve = orbit_solver(primary, truth)
args = (primary.pixel, primary.scan, jnp.mean(primary.longitude))
radius = float(first.orbit.radius)
runs = 12
latitude = np.asarray(primary.latitude) + rng.normal(size=(runs, len(primary))) * np.asarray(primary.sigma) / radius
longitude = np.asarray(primary.longitude) + rng.normal(size=(runs, len(primary))) * np.asarray(primary.sigma) / (
    radius * np.cos(np.asarray(primary.latitude)))
fit = lambda lat, lon: solve({"latitude": lat, "longitude": lon}, args).parameters
sharded = sharded_vmap(fit)(latitude, longitude)
plain = jax.jit(jax.vmap(fit))  # the unsharded program, on each device's share of the realizations
halves = [plain(latitude[k:k + runs // 2], longitude[k:k + runs // 2]) for k in (0, runs // 2)]


def table(models):  # (unknowns, realizations)
    return np.stack([np.concatenate([np.asarray(getattr(m, f)) for m in models]) for f in SCAN_UNKNOWNS])

np.savez(sys.argv[1], linear=linear, split=np.array(split), sharded=table([sharded]), unsharded=table(halves))
"""


@pytest.mark.slow
def test_sharded_realizations_equal_unsharded_on_two_host_devices(tmp_path):
    """Two host devices need a subprocess (the device count is fixed when JAX starts). The XLA CPU runtime there
    gets 4 threads (NPROC): two devices run their batched LAPACK kernels at once, and on a pool of fewer threads
    than kernels plus one each waits for ever (the deadlock of seaice_jax._small_linalg's note)."""
    out = tmp_path / "results.npz"
    flags = "--xla_force_host_platform_device_count=2 --xla_cpu_multi_thread_eigen=false"
    environment = {**os.environ, "NPROC": "4", "XLA_FLAGS": f"{os.environ.get('XLA_FLAGS', '')} {flags}"}
    subprocess.run([sys.executable, "-c", _SHARDED, str(out)], env=environment, check=True, timeout=400)
    with np.load(out) as results:
        linear, split, sharded, unsharded = (results[k] for k in ("linear", "split", "sharded", "unsharded"))
    assert linear.shape == (2, 9, 3) and np.array_equal(linear[0], linear[1])  # bit for bit
    assert split.tolist() == [[5, 3], [5, 3]]  # each device holds half the realizations
    assert sharded.shape == (5, 12) and np.all(np.isfinite(sharded))
    assert np.all(np.ptp(sharded, axis=1) > 0)  # twelve different realizations, not one repeated
    np.testing.assert_allclose(sharded, unsharded, rtol=1e-12, atol=0)
