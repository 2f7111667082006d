"""Orbit fits on input that cannot work one way: ``direction="auto"`` survives a direction whose start puts control
points beyond the horizon (NaN positions and Jacobians), and Appendix C on two points is refused by name instead of
running its loops to their caps."""

import numpy as np
import pytest

from seaice_jax.adjust.orbit.fit import fit_scan_model, initial_guess
from seaice_jax.cli import main
from seaice_jax.errors import RankDeficiencyError
from seaice_jax.geometry.scan import ScanModel, satellite_orbit
from seaice_jax.simulate.satellite import noaa_image, simulate_control_points


def test_auto_survives_a_direction_whose_start_sees_past_the_horizon():
    """A full AVHRR-wide swath (scanner angles ±55° at 857 km): the northbound start for a southbound image puts
    control points where the scanner's line of sight misses the Earth; auto keeps the southbound fit."""
    orbit = satellite_orbit("NOAA-7")
    truth = ScanModel(np.radians(110.0), 256.0, np.radians(99.0), np.radians(20.0), np.radians(66.0), orbit, "south")
    control, _, _ = simulate_control_points(truth, 10, np.random.default_rng(0), 1000.0, margin=2.0)
    wrong = initial_guess(control, orbit, "north", truth.n_pixels, truth.n_scans)
    latitude, _ = wrong.forward_unchecked(control.pixel, control.scan)
    assert np.isnan(np.asarray(latitude)).any()  # the wrong start really cannot be evaluated everywhere
    fit = fit_scan_model(control, orbit, direction="auto", n_pixels=truth.n_pixels, n_scans=truth.n_scans)
    assert fit.model.direction == "south" and list(fit.alternatives) == ["south"]  # the northbound fit failed cleanly
    pixel, scan = np.meshgrid(np.linspace(1, 512, 5), np.linspace(1, 512, 5))
    fitted = np.stack([np.asarray(a) for a in fit.model.forward(pixel, scan)])
    expected = np.stack([np.asarray(a) for a in truth.forward(pixel, scan)])
    km = np.hypot(fitted[0] - expected[0], (fitted[1] - expected[1]) * np.cos(expected[0])) * orbit.radius / 1000
    assert km.max() < 5.0  # 10 points of ±1 km over a 3000 km swath


def test_appendix_c_on_two_points_is_refused_by_name(tmp_path, capsys):
    truth = noaa_image("south")
    control, _, _ = simulate_control_points(truth, 2, np.random.default_rng(1))
    for direction in ("south", "auto"):
        with pytest.raises(RankDeficiencyError, match=r"2 control point\(s\) give 4 observations for the 5 unknowns: "
                                                      r"the observations cannot determine .*at least 3 points"):
            fit_scan_model(control, truth.orbit, direction=direction, method="appendix_c",
                           n_pixels=truth.n_pixels, n_scans=truth.n_scans)
    with pytest.raises(RankDeficiencyError, match="cannot determine") as info:  # both directions: still by name
        fit_scan_model(control, truth.orbit, direction="auto", n_pixels=truth.n_pixels, n_scans=truth.n_scans)
    assert info.value.parameters
    two = tmp_path / "two.csv"
    two.write_text("id,pixel,scan,lat,lon\nA,10,20,75,-80\nB,300,400,73,-78\n")
    assert main(["rectify", str(two), "--satellite", "NOAA-7", "--method", "appendix_c"]) == 2
    error = capsys.readouterr().err
    assert "cannot determine" in error and "Traceback" not in error
