"""The image-sequence workflow through the command line, on a small simulated sequence, and its errors."""

import json

import numpy as np
import pytest

from seaice_jax.cli import main
from seaice_jax.errors import SeaiceError
from seaice_jax.imagery.tracking import MIXED_MOTION, ON_LAND
from seaice_jax.io.remapped import load_remapped
from seaice_jax.io.sequence import read_sequence
from seaice_jax.simulate.satellite import simulate_sequence, true_displacement
from seaice_jax.workflows.simulated_sequence import SIMULATED_GRID, write_simulated_sequence


@pytest.fixture(scope="module")
def workflow(tmp_path_factory):
    root = tmp_path_factory.mktemp("sequence")
    sequence = simulate_sequence(5, n_images=3, size=128)
    project = write_simulated_sequence(root / "project", sequence=sequence)
    assert main(["remap", str(project), "--out", str(root / "remapped"), "--quiet"]) == 0
    assert main(["track", str(root / "remapped"), "--out", str(root / "drift"), "--quiet"]) == 0
    assert main(["velocities", str(root / "drift" / "floes.csv"), "--out", str(root / "velocities"),
                 "--box-km", "100"]) == 0
    assert main(["movie", str(root / "remapped"), "--out", str(root / "film.gif"), "--land-mask",
                 str(root / "project" / "land_mask.npy"), "--records", str(root / "drift" / "floes.csv")]) == 0
    return root, sequence


def test_remap_writes_georeferenced_images_and_rectification(workflow):
    import tifffile

    root, sequence = workflow
    stack = load_remapped(root / "remapped")
    assert stack.values.shape == (3, *SIMULATED_GRID["shape"]) and stack.names == ("IMG01", "IMG02", "IMG03")
    with tifffile.TiffFile(root / "remapped" / "IMG02.tif") as tif:
        metadata = tif.geotiff_metadata
        assert metadata is not None and metadata["ProjectedCSTypeGeoKey"] == 3413
        np.testing.assert_array_equal(tif.pages[0].asarray(), stack.values[1].astype(np.float32))
    # the fitted models put the control points within a few km, and the geolocation σ is of that order
    deviations = np.genfromtxt(root / "remapped" / "rectification.csv", delimiter=",", names=True, dtype=None,
                               encoding=None)
    distance = np.hypot(deviations["north_km"], deviations["east_km"])
    assert distance.mean() < 4.0
    assert 200.0 < np.nanmedian(stack.sigma) < 3000.0
    assert (root / "remapped" / "remapped.png").exists()


def test_track_writes_cf_drift_whose_vectors_follow_the_ice(workflow):
    import xarray as xr

    root, sequence = workflow
    with xr.open_dataset(root / "drift" / "drift_IMG01_IMG02.nc") as ds:
        x, y = np.meshgrid(ds["xc"].values, ds["yc"].values)
        dx, dy = ds["dX"].values[0], ds["dY"].values[0]
        sigma = ds["dX_uncertainty"].values[0]
        at_sea = ds["status_flag"].values[0] != ON_LAND  # land is masked by default (GSHHG)
        coastal = ds["status_flag"].values[0] == MIXED_MOTION  # land in the patch, or the fast-ice edge
        assert ds["u_grid"].attrs["long_name"].startswith("velocity along the grid's x axis")
        assert ds["u_east"].attrs["standard_name"] == "eastward_sea_ice_velocity"
        assert ds["divergence"].size > 10 and "divergence_uncertainty" in ds["divergence"].attrs[
            "ancillary_variables"]
        assert np.all(ds["divergence_uncertainty"].values > 0)
    good = np.isfinite(dx)
    # a scene of sounds and coasts: most vectors at sea have land or the fast-ice edge in their patch
    assert (good | coastal)[at_sea].mean() > 0.5 and good.sum() > 10 and 0.1 < 1 - at_sea.mean() < 0.6
    first, second = sequence.images[:2]
    truth = true_displacement(sequence.scene, np.stack([x[good], y[good]], 1), first.time, second.time)
    error = np.hypot(dx[good] - truth[:, 0], dy[good] - truth[:, 1])
    # geolocation of two images rectified on land control (km), not the tracking, dominates; the stated σ says so
    assert np.sqrt(np.mean(error**2)) < 3.0 * np.sqrt(2) * np.median(sigma[good])
    assert (root / "drift" / "drift_IMG02_IMG03.png").read_bytes()[:4] == b"\x89PNG"
    floes = np.genfromtxt(root / "drift" / "floes.csv", delimiter=",", names=True, dtype=None, encoding=None)
    assert set(floes["image"]) == {"IMG01", "IMG02", "IMG03"}
    collection = json.loads((root / "drift" / "trajectories.geojson").read_text())
    assert any(f["geometry"]["type"] == "LineString" and len(f["properties"]["times"]) == 3
               for f in collection["features"])


def test_track_layout_osisaf_writes_both_layouts_of_the_same_vectors(workflow, tmp_path):
    """``--layout osisaf`` on the remapped sequence: the OSI SAF file beside each project-layout file, with the
    vectors of the project layout (in km) and its status codes; the project-layout file that of the default run."""
    import pyogrio
    import xarray as xr

    from seaice_jax.io.products import TO_OSISAF_STATUS

    root, _ = workflow
    assert main(["track", str(root / "remapped"), "--out", str(tmp_path / "drift"), "--quiet", "--layout",
                 "osisaf"]) == 0
    own_paths = sorted((tmp_path / "drift").glob("drift_*[!f].nc"))
    assert [p.name for p in own_paths] == ["drift_IMG01_IMG02.nc", "drift_IMG02_IMG03.nc"]
    for own_path in own_paths:
        osi_path = own_path.with_name(own_path.stem + "_osisaf.nc")
        with (xr.open_dataset(own_path) as own, xr.open_dataset(osi_path) as osi,
              xr.open_dataset(root / "drift" / own_path.name) as default):
            good = np.isfinite(own["dX"].values)
            assert good.sum() > 5  # most vectors at sea are by a coast or the fast-ice edge (MIXED_MOTION)
            np.testing.assert_array_equal(own["dX"].values, default["dX"].values)
            np.testing.assert_allclose(osi["dX"].values[good] * 1000.0, own["dX"].values[good], rtol=1e-6)
            expected = np.vectorize(TO_OSISAF_STATUS.get)(own["status_flag"].values)
            np.testing.assert_array_equal(osi["status_flag"].values, expected)
            assert osi["dX"].attrs["units"] == "km" and osi["time_bnds"].equals(own["time_bnds"])
    assert not list((root / "drift").glob("*_osisaf.nc"))  # the default layout writes no OSI SAF file
    assert pyogrio.read_info(tmp_path / "drift" / "fixes.geojson")["geometry_type"] == "Point"
    assert pyogrio.read_info(tmp_path / "drift" / "trajectories.geojson")["geometry_type"] == "LineString"


def test_velocities_and_film(workflow):
    from PIL import Image

    root, _ = workflow
    for name in ("velocities.csv", "box_averages.csv", "box_averages.png", "velocity_series.png",
                 "deformation.csv", "trajectories.geojson", "trajectories.png"):
        assert (root / "velocities" / name).stat().st_size > 0
    table = np.genfromtxt(root / "velocities" / "velocities.csv", delimiter=",", names=True, dtype=None,
                          encoding=None)
    np.testing.assert_allclose(np.hypot(table["u_grid_m_s"], table["v_grid_m_s"]),
                               np.hypot(table["u_east_m_s"], table["v_north_m_s"]), rtol=1e-7)  # CSV: 9 digits
    with Image.open(root / "film.gif") as film:
        assert getattr(film, "n_frames", 1) == 3  # a GIF's frames (not on PIL's base ImageFile type)


def write_project(tmp_path, text):
    path = tmp_path / "sequence.toml"
    path.write_text(text)
    return path


GOOD_HEAD = 'epoch = "1983-03-08T00:00:00Z"\n[grid]\ncentre_deg = [74.0, -85.0]\npixel_m = [2500.0, 2500.0]\n' \
            'shape = [10, 10]\n'


@pytest.mark.parametrize("body, message", [
    ('[[image]]\nname = "A"\ntime = "1983-03-32T00:00:00Z"\nfile = "a.npy"\ncontrol = "c.csv"\n',
     r"image 'A': time '1983-03-32T00:00:00Z' is not an ISO 8601 date-time"),
    ('[[image]]\nname = "A"\ntime = "1983-03-08T01:00:00Z"\nfile = "missing.npy"\ncontrol = "c.csv"\n',
     r"missing.npy: file not found"),
    ('[[image]]\nname = "A"\ntime = "1983-03-08T01:00:00Z"\nfile = "a.npy"\n',
     r"image 'A': give either control = 'file.csv' or the scan model"),
    ('[[image]]\nname = "A"\ntime = "1983-03-08T01:00:00Z"\nfile = "a.npy"\ncontrol = "c.csv"\n'
     '[[image]]\nname = "A"\ntime = "1983-03-09T01:00:00Z"\nfile = "a.npy"\ncontrol = "c.csv"\n',
     r"image 'A': duplicate image name"),
    ('[[image]]\nname = "A"\ntime = "1983-03-09T01:00:00Z"\nfile = "a.npy"\ncontrol = "c.csv"\n'
     '[[image]]\nname = "B"\ntime = "1983-03-08T01:00:00Z"\nfile = "a.npy"\ncontrol = "c.csv"\n',
     r"image times must increase"),
    ('[[image]]\nname = "A"\ntime = "1983-03-08T01:00:00Z"\nfile = "a.npy"\ncontrol = "bad.csv"\n',
     r"bad.csv, line 2: column 'scan' value 'x' is not a number"),
])
def test_sequence_project_errors_name_the_entry(tmp_path, body, message):
    np.save(tmp_path / "a.npy", np.zeros((8, 8)))
    (tmp_path / "c.csv").write_text("id,pixel,scan,latitude,longitude,sigma_m\nP1,1,1,74,-85,500\n")
    (tmp_path / "bad.csv").write_text("id,pixel,scan,latitude,longitude,sigma_m\nP1,1,x,74,-85,500\n")
    path = write_project(tmp_path, GOOD_HEAD + body)
    with pytest.raises(SeaiceError, match=message):
        read_sequence(path)


def test_cli_errors_are_one_line_and_write_nothing(tmp_path, capsys, workflow):
    root, _ = workflow
    path = write_project(tmp_path, 'epoch = "1983-03-08T00:00:00Z"\n')
    assert main(["remap", str(path), "--out", str(tmp_path / "out"), "--quiet"]) == 2
    assert "a [grid] table is needed" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()
    assert main(["movie", str(root / "remapped"), "--out", str(tmp_path / "film.avi")]) == 2
    assert "written as .gif or .mp4" in capsys.readouterr().err
    assert not (tmp_path / "film.avi").exists()
    old = tmp_path / "old"
    old.mkdir()
    with np.load(root / "remapped" / "remapped.npz") as data:
        np.savez(old / "remapped.npz", **{k: data[k] for k in data.files if k != "covariance"})
    assert main(["track", str(old), "--out", str(tmp_path / "drift"), "--quiet"]) == 2
    assert "remapped.npz: no covariance" in capsys.readouterr().err
    assert not (tmp_path / "drift").exists()
