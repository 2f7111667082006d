import ctypes
import gc
import os
import shutil
import tempfile

# One XLA CPU intra-op thread. jaxlib's batched LAPACK kernels (QR, SVD, ... under vmap) split the batch into tasks
# on the intra-op pool and block until they are done; when every pool thread runs such a kernel at once (two on a
# two-core machine: the executor runs independent kernels concurrently) no thread is left to run the tasks and the
# process waits forever, idle. With one thread the kernels run their batch inline. Set before JAX makes its CPU
# client; the `seaice` subprocesses of the tests inherit it.
os.environ["NPROC"] = "1"
# One OpenBLAS thread (as the `seaice` command sets it): with XLA's thread and the other test process on two cores,
# OpenBLAS's spinning threads made small factorizations hundreds of times slower.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import jax
import numpy as np
import pytest
from hypothesis import settings

from seaice_jax import _config  # noqa: F401  (float64)
from seaice_jax.cli import CACHE_VARIABLE

jax.config.update("jax_numpy_rank_promotion", "raise")
settings.register_profile("seaice", max_examples=40, deadline=None, derandomize=True)
settings.load_profile("seaice")

# One persistent JAX compilation cache for the whole test session, in a temporary folder made by the first process
# (the xdist controller, or the only process) and inherited through the environment by the xdist workers, the
# `seaice` and Python subprocesses and the Dask worker processes: an executable compiled once is read back by every
# other process instead of compiled again (the same executable: the same results). `SEAICE_TEST_JAX_CACHE_DIR=
# make test` runs the suite without it.
SESSION_CACHE_VARIABLE = "SEAICE_TEST_JAX_CACHE_DIR"
_OWNS_SESSION_CACHE = SESSION_CACHE_VARIABLE not in os.environ
if _OWNS_SESSION_CACHE:
    os.environ[SESSION_CACHE_VARIABLE] = tempfile.mkdtemp(prefix="seaice-test-jax-")
SESSION_CACHE = os.environ[SESSION_CACHE_VARIABLE]
if SESSION_CACHE:
    every = {"jax_persistent_cache_min_compile_time_secs": 0.0, "jax_persistent_cache_min_entry_size_bytes": 0}
    for name, value in {"jax_compilation_cache_dir": SESSION_CACHE, **every}.items():
        jax.config.update(name, value)
        os.environ[name.upper()] = str(value)  # the subprocesses' JAX
os.environ[CACHE_VARIABLE] = SESSION_CACHE  # `seaice` runs use the session's cache (empty: none), not the user's


def pytest_unconfigure(config):
    if _OWNS_SESSION_CACHE and not hasattr(config, "workerinput"):
        shutil.rmtree(SESSION_CACHE, ignore_errors=True)


@pytest.fixture
def rng():
    return np.random.default_rng(20261124)


_LIBC = ctypes.CDLL(None)


def _drop_compilations():
    """Drop the process's compiled executables and hand the freed heap back to the system (glibc's
    ``malloc_trim``); a later test that needs an executable again reads it from the session's persistent cache."""
    jax.clear_caches()
    gc.collect()
    if hasattr(_LIBC, "malloc_trim"):  # glibc
        _LIBC.malloc_trim(0)


@pytest.fixture(autouse=True, scope="module")
def _compilations_of_one_file():
    """Each test file's compiled executables are dropped when it ends: a test process runs many files, and their
    memory piled up. Measured in one process: 12 files peaked at 3.9 GB in 143 s keeping the executables, 1.3 GB
    in 152 s dropping them (the later files trace again and read the cache); 5 files left 1.76 GB resident without
    the trim, 0.94 GB with it."""
    yield
    _drop_compilations()


RESIDENT_CEILING = 2.0e9
"""Bytes resident after a test above which the process drops its compilations at once, not at the end of the file
(a file of several command-line pipelines, tests/test_sequence_block.py, reached 2.3 GB)."""


@pytest.fixture(autouse=True)
def _compilations_beyond_the_ceiling():
    yield
    if os.path.exists("/proc/self/statm"):  # Linux: the pages resident now
        with open("/proc/self/statm") as statm:
            if int(statm.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") > RESIDENT_CEILING:
                _drop_compilations()
