import os

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
