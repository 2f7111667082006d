"""An image straddling ±180° longitude fits to the same accuracy as the same image elsewhere (the longitudes are
compared modulo 360°)."""

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

from seaice_jax.adjust.orbit.fit import fit_scan_model
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
        fits.append(fit_scan_model(control, model.orbit, direction=direction, n_pixels=model.n_pixels,
                                   n_scans=model.n_scans))
    here, there = fits
    assert there.rms_km == pytest.approx(here.rms_km, rel=1e-6, abs=1e-9)
    # the same solution to the fit's own convergence (1e-7 rad: 0.6 m on the ground; the node's σ is 3e-3 rad)
    assert float(wrap_angle(there.model.ascending_node - here.model.ascending_node - shift)) == pytest.approx(
        0.0, abs=1e-7)
    assert float(there.model.subtrack_pixel) == pytest.approx(float(here.model.subtrack_pixel), abs=1e-6)


def _rotated(model, shift):
    return eqx.tree_at(lambda m: m.ascending_node, model, model.ascending_node + shift)


@pytest.mark.parametrize("approximate", [0.0, 0.05])
def test_remapping_across_the_antimeridian_equals_remapping_elsewhere(approximate):
    """Turning the orbit's node and the grid's centre by the same angle moves nothing relative to each other, so
    an image remapped onto an equirectangular grid across ±180° equals the same image remapped at 85°W."""
    from seaice_jax.imagery.remap import remap
    from seaice_jax.io.sequence import make_grid

    model = noaa_image("south")
    shift = np.radians(180.0 - -85.0)
    image = np.add.outer(np.sin(np.arange(512) / 9.0), np.cos(np.arange(512) / 13.0))
    here = make_grid("equirectangular", [74.0, -85.0], [5000.0, 5000.0], [24, 32])
    there = make_grid("equirectangular", [74.0, 180.0], [5000.0, 5000.0], [24, 32])
    lon = np.degrees(np.asarray(there.projection.inverse(*there.xy())[1]))
    assert lon.min() < -179 and lon.max() > 179  # the grid really straddles ±180°
    a, valid_a = remap([image], [model], here, max_error_pixels=approximate)
    b, valid_b = remap([image], [_rotated(model, shift)], there, max_error_pixels=approximate)
    assert valid_a.sum() > 0.9 * valid_a.size
    np.testing.assert_array_equal(valid_a, valid_b)
    np.testing.assert_allclose(b[valid_b], a[valid_a], atol=1e-6)


GRIDS = {  # projection, centre (degrees): the grid straddles ±180°, or contains a pole
    "antimeridian": ("nsidc-north", [74.0, 180.0]),
    "antimeridian, equirectangular": ("equirectangular", [74.0, 180.0]),
    "antimeridian, south": ("nsidc-south", [-70.0, -180.0]),
    "north pole": ("nsidc-north", [90.0, 0.0]),
    "south pole": ("nsidc-south", [-90.0, 30.0]),
    "ordinary": ("nsidc-north", [74.0, -85.0]),
}


@pytest.mark.parametrize("case", list(GRIDS))
def test_drift_products_across_the_antimeridian_and_at_the_poles(tmp_path, case):
    """The drift file's positions are the grid's (x, y) through the inverse projection wherever the grid lies, and
    its ACDD bounds are the smallest box holding them: across ±180° ``geospatial_lon_min > geospatial_lon_max``;
    with a pole inside, every longitude and the pole's latitude."""
    import xarray as xr

    from seaice_jax.imagery.tracking import STATUS
    from seaice_jax.io.products import write_drift_netcdf
    from seaice_jax.io.sequence import make_grid

    projection, centre = GRIDS[case]
    grid = make_grid(projection, centre, [5000.0, 5000.0], [6, 8])
    fields = {"dX": np.full(grid.shape, 1500.0), "dY": np.full(grid.shape, -700.0),
              "dX_uncertainty": np.full(grid.shape, 200.0), "dY_uncertainty": np.full(grid.shape, 250.0),
              "status_flag": np.zeros(grid.shape, int), "u_east": np.zeros(grid.shape),
              "v_north": np.zeros(grid.shape)}
    write_drift_netcdf(tmp_path / "drift.nc", grid, fields, 3600.0, 90000.0, "1983-03-08T00:00:00Z", STATUS)
    with xr.open_dataset(tmp_path / "drift.nc") as ds:
        lat, lon = (np.asarray(ds[k].values, float) for k in ("lat", "lon"))
        attrs = ds.attrs
    x, y = (np.asarray(a) for a in grid.xy())
    back = np.asarray(grid.projection.forward(np.radians(lat), np.radians(lon)))
    np.testing.assert_allclose(back, np.stack([x, y]), atol=0.01)  # each cell's own position, not wrapped wrongly
    west, east = attrs["geospatial_lon_min"], attrs["geospatial_lon_max"]
    if "pole" in case:
        assert (west, east) == (-180.0, 180.0)
        assert attrs["geospatial_lat_max" if centre[0] > 0 else "geospatial_lat_min"] == centre[0]
        return
    width = (east - west) % 360.0
    assert width < 2.0  # 40 km of grid at 70-74°N or S: 1.4° of longitude, not the whole globe
    assert np.all((lon - west) % 360.0 <= width + 1e-9)  # and it holds every cell
    assert (west > east) == case.startswith("antimeridian")
    assert attrs["geospatial_lat_min"] == pytest.approx(lat.min()) and attrs["geospatial_lat_max"] == pytest.approx(
        lat.max())
