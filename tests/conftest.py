import jax
import numpy as np
import pytest
from hypothesis import settings

import seaice_jax  # noqa: F401  (enables float64)

jax.config.update("jax_numpy_rank_promotion", "raise")
settings.register_profile("seaice", max_examples=40, deadline=None, derandomize=True)
settings.load_profile("seaice")


@pytest.fixture
def rng():
    return np.random.default_rng(20261124)
