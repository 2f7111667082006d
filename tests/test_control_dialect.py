"""One control-point CSV dialect: the control files ``seaice simulate lancaster`` writes go straight into ``seaice
rectify`` (no conversion), and the older column names (the 1985 example's ``lat``/``lon``, ``sigma_km``) still
read with their units."""

import json

import numpy as np
import pytest

from seaice_jax.cli import main
from seaice_jax.errors import SeaiceError
from seaice_jax.geometry.scan import SCAN_UNKNOWNS
from seaice_jax.io.remapped import load_models
from seaice_jax.io.sequence import read_sequence
from seaice_jax.io.stations import MEASUREMENT_COLUMNS, control_points, read_measurements
from seaice_jax.report.text import scan_model_from_json

SIZE = 64


def test_simulated_control_points_rectify_directly(tmp_path):
    project = tmp_path / "sim"
    assert main(["simulate", "lancaster", "--out", str(project), "--images", "1", "--size", str(SIZE), "-q"]) == 0
    control = project / "IMG01_control.csv"
    assert control.read_text().splitlines()[0] == ",".join(MEASUREMENT_COLUMNS)
    points = read_measurements(control)
    assert len(points) == 12 and all(p.sigma_m is not None and 4000 < p.sigma_m < 6000 for p in points)

    fit_json = tmp_path / "fit.json"
    # The pass direction is known to a user (and is in the simulated project's sequence.toml); with the 12 points
    # clustered on land a few km apart, --direction auto can prefer the mirrored fit.
    assert main(["rectify", str(control), "--satellite", "NOAA-7", "--altitude", "0", "--pixels", str(SIZE),
                 "--scans", str(SIZE), "--direction", "south", "--json", str(fit_json), "-q"]) == 0
    document = json.loads(fit_json.read_text())
    # The file's σ (about 5 km: map accuracy and pointing) was used, not --sigma's 1 km default: with the default the
    # normalised residuals would be about 5 times too large (σ̂0 near 5); 19 degrees of freedom put σ̂0 within
    # [0.50, 1.52] with 99.9 % probability.
    assert 0.50 < document["sigma0"] < 1.52
    fitted, covariance = scan_model_from_json(document)
    truth, _, _ = load_models(project / "truth" / "models.npz", read_sequence(project / "sequence.toml"))
    assert truth[0].direction == "south" and covariance is not None
    error = np.array([float(getattr(fitted, u)) - float(getattr(truth[0], u)) for u in SCAN_UNKNOWNS])
    # The fitted unknowns against the truth in the fit's own covariance: χ² with 5 degrees of freedom, below 20.5
    # with 99.9 % probability.
    assert error @ np.linalg.solve(covariance, error) < 20.5


def test_older_column_names_read_with_their_units(tmp_path):
    older = tmp_path / "older.csv"
    older.write_text("id,name,pixel,scan,lat,lon,sigma_km\nA,Alpha,10,20,75.5,-80.25,0.5\n")
    current = tmp_path / "current.csv"
    current.write_text("id,pixel,scan,latitude_deg,longitude_deg,sigma_m,name\nA,10,20,75.5,-80.25,500,Alpha\n")
    a, b = read_measurements(older)[0], read_measurements(current)[0]
    assert (a.id, a.name, a.pixel, a.scan, a.latitude_deg, a.longitude_deg, a.sigma_m) == \
        (b.id, b.name, b.pixel, b.scan, b.latitude_deg, b.longitude_deg, b.sigma_m) == \
        ("A", "Alpha", 10.0, 20.0, 75.5, -80.25, 500.0)
    np.testing.assert_allclose(control_points([a]).sigma, 500.0)


@pytest.mark.parametrize(("content", "message"), [
    ("id,pixel,scan,lat,latitude_deg,longitude_deg\nA,1,2,70,70,0\n",
     r"both.csv, line 1: columns 'lat' and 'latitude_deg' both give latitude; keep one"),
    ("id,pixel,scan,latitude_deg,longitude_deg,sigma_m,sigma_km\nA,1,2,70,0,5,5\n",
     r"both.csv, line 1: columns 'sigma_m' and 'sigma_km' both give sigma_m; keep one"),
    ("id,pixel,scan\nA,1,2\n", r"both.csv, line 1: missing column\(s\) latitude_deg, longitude_deg"),
    ("id,pixel,scan,latitude_deg,longitude_deg,sigma_m\nA,1,2,70,0,-5\n",
     r"both.csv, line 2: point A sigma_m must be > 0"),
    ("id,pixel,scan,latitude_deg,longitude_deg\nA,1,2,70,0,9\n",
     r"both.csv, line 2: more values than the header's 5 columns"),
])
def test_ambiguous_or_bad_columns_are_refused(tmp_path, content, message):
    path = tmp_path / "both.csv"
    path.write_text(content)
    with pytest.raises(SeaiceError, match=message):
        read_measurements(path)
