"""An image straddling ±180° longitude fits to the same accuracy as the same image elsewhere (the longitudes are
compared modulo 360°)."""

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

from seaice_jax.adjust.orbit_fit import fit_scan_model
from seaice_jax.geometry.earth import wrap_angle
from seaice_jax.simulate.satellite import noaa_image, simulate_control_points


@pytest.mark.parametrize("direction", ["south", "north"])
def test_an_image_across_the_antimeridian_fits_as_well_as_elsewhere(direction):
    truth = noaa_image(direction)
    _, centre = truth.forward(jnp.asarray(256.0), jnp.asarray(256.0))
    shift = np.pi - float(centre)
    across = eqx.tree_at(lambda m: m.ascending_node, truth, truth.ascending_node + shift)
    corners = np.degrees(np.asarray(across.forward(jnp.array([1.0, 512.0, 1.0, 512.0]),
                                                   jnp.array([1.0, 1.0, 512.0, 512.0]))[1]))
    assert corners.min() < -170 and corners.max() > 170  # the image really straddles ±180°
    fits = []
    for model in (truth, across):
        control, _, _ = simulate_control_points(model, 10, np.random.default_rng(5), 1000.0)
        fits.append(fit_scan_model(control, model.orbit, direction=direction))
    here, there = fits
    assert there.rms_km == pytest.approx(here.rms_km, rel=1e-6, abs=1e-9)
    assert float(wrap_angle(there.model.ascending_node - here.model.ascending_node - shift)) == pytest.approx(
        0.0, abs=1e-9)
    assert float(there.model.subtrack_pixel) == pytest.approx(float(here.model.subtrack_pixel), abs=1e-6)
