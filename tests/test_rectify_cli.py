import json
from pathlib import Path

import numpy as np
import pytest

from seaice_jax.adjust.orbit.fit import fit_scan_model
from seaice_jax.cli import main
from seaice_jax.report.text import orbit_fit_json, orbit_fit_report
from seaice_jax.simulate.satellite import noaa_image, simulate_control_points

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def write_points(path, control, names=None):
    lines = ["id,pixel,scan,lat,lon"]
    for k, point in enumerate(control.ids):
        lines.append(f"{point},{float(control.pixel[k]):.4f},{float(control.scan[k]):.4f},"
                     f"{np.degrees(float(control.latitude[k])):.8f},{np.degrees(float(control.longitude[k])):.8f}")
    path.write_text("\n".join(lines) + "\n")
    return path


def test_rectify_figure_3_3_prints_the_1985_layout_and_writes_json(tmp_path, capsys):
    measurements = EXAMPLES / "figure_3_3.csv"
    out = tmp_path / "fit.json"
    code = main(["rectify", str(measurements), "--satellite", "NOAA-7", "--altitude", "0", "--earth-day", "1440",
                 "--json", str(out)])
    assert code == 0
    text = capsys.readouterr().out
    assert "DIRECTION OF ORBIT CHOSEN AS SOUTHWARD" in text and "SUBTRACK PIXEL" in text and "DEV" in text
    assert "COB IS ICE" in text
    data = json.loads(out.read_text())
    parameters = data["parameters"]
    assert set(parameters) == {"scanner_angle_first_deg", "scanner_angle_last_deg", "orbital_angle_first_deg",
                               "orbital_angle_last_deg", "subtrack_pixel", "ascending_node_deg", "direction"}
    assert parameters["direction"] == "south"
    assert abs(parameters["subtrack_pixel"] - 112) <= 5
    assert abs(parameters["ascending_node_deg"] - 66.65) <= 0.5
    assert data["rms_km"] <= 1.25
    assert [s["id"] for s in data["stations"]] == ["3030", "3031", "3032", "3034", "3035"]
    assert all(set(s) >= {"id", "dlat_arcmin", "dlon_arcmin", "flagged"} for s in data["stations"])
    assert data["dev_lat_arcmin"] == pytest.approx(np.std([s["dlat_arcmin"] for s in data["stations"]], ddof=1))
    assert data["sigma0"] > 0


def test_rectify_with_the_agrid_catalogue_gives_the_same_fit(tmp_path, capsys):
    out_direct, out_catalogue = tmp_path / "a.json", tmp_path / "b.json"
    common = ["--satellite", "NOAA-7", "--altitude", "0", "--earth-day", "1440", "--direction", "south"]
    assert main(["rectify", str(EXAMPLES / "figure_3_3.csv"), *common, "--json", str(out_direct)]) == 0
    assert main(["rectify", str(EXAMPLES / "figure_3_3_measured.csv"), "--stations", str(EXAMPLES / "AGRID.STN"),
                 *common, "--json", str(out_catalogue)]) == 0
    a, b = (json.loads(p.read_text())["parameters"] for p in (out_direct, out_catalogue))
    assert a["subtrack_pixel"] == pytest.approx(b["subtrack_pixel"], abs=1e-3)  # coordinates rounded to 1e-6°


def test_rectify_with_check_points_reports_them_separately(tmp_path, capsys):
    truth = noaa_image("south", altitude=0.0)
    rng = np.random.default_rng(8)
    control, _, _ = simulate_control_points(truth, 7, rng, 800.0)
    check, _, _ = simulate_control_points(truth, 4, rng, 800.0)
    out = tmp_path / "fit.json"
    code = main(["rectify", str(write_points(tmp_path / "gcp.csv", control)), "--satellite", "NOAA-7",
                 "--altitude", "0", "--sigma", "0.8", "--check", str(write_points(tmp_path / "chk.csv", check)),
                 "--json", str(out)])
    assert code == 0
    assert "CHECK POINTS (not used in the fit)" in capsys.readouterr().out
    data = json.loads(out.read_text())
    assert [c["id"] for c in data["check"]] == list(check.ids)
    errors = np.array([c["error_km"] for c in data["check"]])
    assert data["check_rmse_km"] == pytest.approx(np.sqrt(np.mean(errors**2)))
    assert 0.0 < data["check_rmse_km"] < 3.0  # check points carry their own 0.8 km noise


def test_rectify_errors_name_the_file_and_write_nothing(tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    bad.write_text("id,pixel,scan,lat,lon\nA,1,2,70,0\nB,x,2,70,0\n")
    out = tmp_path / "fit.json"
    assert main(["rectify", str(bad), "--satellite", "NOAA-7", "--json", str(out)]) == 2
    assert "bad.csv, line 3: column 'pixel' value 'x' is not a number" in capsys.readouterr().err
    assert not out.exists()
    assert main(["rectify", str(bad), "--satellite", "NOAA-99"]) == 2
    too_few = tmp_path / "two.csv"
    too_few.write_text("id,pixel,scan,lat,lon\nA,10,20,75,-80\nB,300,400,73,-78\n")
    assert main(["rectify", str(too_few), "--satellite", "NOAA-7", "--altitude", "0", "--direction", "south"]) == 2
    assert "cannot determine" in capsys.readouterr().err


@pytest.mark.slow
def test_report_for_appendix_c_has_no_invented_statistics():
    truth = noaa_image("south")
    control, _, _ = simulate_control_points(truth, 6, np.random.default_rng(2), 500.0)
    fit = fit_scan_model(control, truth.orbit, direction="south", method="appendix_c",
                         n_pixels=truth.n_pixels, n_scans=truth.n_scans,
                         search_options={"initial_spans": (5.0, 5.0), "start_subtrack": 128, "search_span": 256})
    data = orbit_fit_json(fit)
    assert data["sigma0"] is None and data["parameter_sigma"] == {}
    assert "POSITION EVALUATIONS" in orbit_fit_report(fit)


def test_rectify_with_the_image_writes_the_coastline_overlay(tmp_path, capsys):
    image = tmp_path / "noaa7.npy"
    np.save(image, np.random.default_rng(0).random((512, 512)))
    out = tmp_path / "fit.json"
    assert main(["rectify", str(EXAMPLES / "figure_3_3.csv"), "--satellite", "NOAA-7", "--altitude", "0",
                 "--earth-day", "1440", "--image", str(image), "--json", str(out)]) == 0
    overlay = tmp_path / "noaa7_overlay.png"
    assert f"wrote {overlay}" in capsys.readouterr().out
    assert overlay.stat().st_size > 10_000 and out.exists()


@pytest.mark.slow
def test_rectify_auto_control_from_a_rough_orbit_recovers_the_pass(tmp_path, capsys):
    """`seaice rectify --image --auto-control` on a simulated image of Lancaster Sound (GSHHG land), from the node
    0.5° and the pass time 20 km off: the fitted parameters are the true ones to a fraction of a pixel."""
    import equinox as eqx

    from seaice_jax.report.text import scan_model_from_json
    from seaice_jax.simulate.satellite import ice_scene, noaa_pass, place_pass, render

    centre = np.radians(73.9), np.radians(-80.5)
    truth = noaa_pass("south", 240, *centre)
    truth = place_pass(eqx.tree_at(lambda m: (m.scanner_angle_span, m.orbital_angle_span), truth,
                                   replace=(0.5 * truth.scanner_angle_span, 0.5 * truth.orbital_angle_span)), *centre)
    scene = ice_scene(np.random.default_rng(3), 73.9, -80.5, extent=500_000.0)
    image = tmp_path / "pass.npy"
    np.save(image, np.asarray(render(scene, truth, 0.0)))
    minutes = float(truth.orbit.period) / 60.0 / (2 * np.pi)  # minutes per radian of orbit
    out = tmp_path / "auto.json"
    assert main(["rectify", "--image", str(image), "--auto-control", "--satellite", "NOAA-7", "--altitude", "0",
                 "--pixels", "240", "--scans", "240", "--node", f"{np.degrees(float(truth.ascending_node)) + 0.5}",
                 "--pass-minutes", f"{(float(truth.orbital_angle_first) + 20e3 / 6.371e6) * minutes}",
                 "--scanner-span", f"{np.degrees(float(truth.scanner_angle_span))}",
                 "--orbital-span", f"{np.degrees(float(truth.orbital_angle_span))}",
                 "--subtrack", f"{float(truth.subtrack_pixel)}", "--search", "24", "--json", str(out)]) == 0
    assert "DIRECTION OF ORBIT ASSUMED TO BE SOUTHWARD" in capsys.readouterr().out  # from the pass time
    fitted, _ = scan_model_from_json(json.loads(out.read_text()))
    pixel, scan = (a.ravel() for a in np.meshgrid(np.linspace(4, 236, 10), np.linspace(4, 236, 10)))
    p, s = (np.asarray(a) for a in fitted.inverse(*truth.forward(pixel, scan)))
    assert np.sqrt(np.mean((p - pixel) ** 2 + (s - scan) ** 2)) < 1.0  # pixels; the start was ~15 off
    assert (tmp_path / "pass_overlay.png").exists()
