import os

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
os.environ[CACHE_VARIABLE] = ""  # the in-process `seaice` calls keep no compilations in the user's cache folder


@pytest.fixture
def rng():
    return np.random.default_rng(20261124)
