"""Text and JSON reports of results (presentation only: the numbers come from the adjust layer)."""

import numpy as np

from seaice_jax import __version__
from seaice_jax.adjust.orbit.fit import OrbitFit
from seaice_jax.errors import SeaiceError
from seaice_jax.geometry.scan import SCAN_UNKNOWNS, Orbit, ScanModel

JSON_FORMAT = "seaice_jax rectify 1"
"""The ``format`` of the ``seaice rectify --json`` document (:func:`orbit_fit_json`)."""

JSON_UNITS = {
    "model.unknowns": "the scan model's unknowns: angles in degrees (keys *_deg), subtrack_pixel in pixels (1-based)",
    "model.orbit": "inclination_deg degrees, period_s and earth_day_s seconds, altitude_m and radius_m metres",
    "model.covariance": "(5, 5) a posteriori covariance (sigma0^2 x cofactor) of model.unknowns in their order and "
                        "units (deg^2, deg x pixel, pixel^2)",
    "model.cofactor": "(5, 5) a priori covariance (J^T P J)^-1 of model.unknowns, same order and units",
    "parameters": "the image-edge angles of the 1985 printout (degrees) and subtrack_pixel (pixels)",
    "*_arcmin": "arc minutes, computed minus known", "*_km": "km on the ground",
}
"""What the numbers of the ``seaice rectify --json`` document are, and their units."""


def _degrees_minutes(value_deg: float) -> str:
    sign = "-" if value_deg < 0 else ""
    minutes = round(abs(value_deg) * 60.0, 2)
    degrees, minutes = divmod(minutes, 60.0)
    return f"{sign}{int(degrees)} {minutes:05.2f}"


def _parameters(fit: OrbitFit) -> dict:
    model = fit.model
    return {
        "scanner_angle_first_deg": float(np.degrees(model.scanner_angle_first)),
        "scanner_angle_last_deg": float(np.degrees(model.scanner_angle_last)),
        "orbital_angle_first_deg": float(np.degrees(model.orbital_angle_first)),
        "orbital_angle_last_deg": float(np.degrees(model.orbital_angle_last)),
        "subtrack_pixel": float(model.subtrack_pixel),
        "ascending_node_deg": float(np.degrees(model.ascending_node)),
        "direction": model.direction,
    }


def _parameter_sigma(fit: OrbitFit) -> dict:
    if fit.adjustment is None:
        return {}
    sigma = fit.adjustment.standard_deviations(a_priori=True)
    out = {}
    for name in SCAN_UNKNOWNS:  # the pixel in pixels, the angles in degrees
        if name == "subtrack_pixel":
            out[name] = float(sigma[name])
        else:
            out[f"{name}_deg"] = float(np.degrees(sigma[name]))
    return out


def _json_key(unknown: str) -> str:
    return unknown if unknown == "subtrack_pixel" else f"{unknown}_deg"


def _json_scale() -> np.ndarray:
    """``(5,)`` factors from the model's units of :data:`SCAN_UNKNOWNS` (radians, pixels) to the JSON's (degrees,
    pixels)."""
    return np.array([1.0 if unknown == "subtrack_pixel" else np.degrees(1.0) for unknown in SCAN_UNKNOWNS])


def _model_json(fit: OrbitFit) -> dict:
    """The scan model (unknowns, orbit, image size, direction) and, for a Gauss-Newton fit, the covariance and
    cofactor of its unknowns: what :func:`scan_model_from_json` rebuilds it from."""
    model, orbit, scale = fit.model, fit.model.orbit, _json_scale()
    result = {
        "unknowns": {_json_key(u): float(getattr(model, u)) * s for u, s in zip(SCAN_UNKNOWNS, scale, strict=True)},
        "direction": model.direction, "n_pixels": model.n_pixels, "n_scans": model.n_scans,
        "orbit": {"inclination_deg": float(np.degrees(orbit.inclination)), "period_s": float(orbit.period),
                  "altitude_m": float(orbit.altitude), "earth_day_s": float(orbit.earth_day),
                  "radius_m": float(orbit.radius)},
    }
    adjustment = fit.adjustment
    if adjustment is not None:
        order = [SCAN_UNKNOWNS.index(name) for name in adjustment.parameter_names]
        for key, matrix in (("covariance", adjustment.covariance), ("cofactor", adjustment.cofactor)):
            in_order = np.empty((len(SCAN_UNKNOWNS),) * 2)
            in_order[np.ix_(order, order)] = np.asarray(matrix)
            result[key] = (scale[:, None] * in_order * scale[None, :]).tolist()
    return result


def scan_model_from_json(document: dict) -> tuple[ScanModel, np.ndarray | None]:
    """The scan model of a ``seaice rectify --json`` document (:func:`orbit_fit_json`) and the a posteriori
    covariance ``(5, 5)`` of its unknowns (:data:`SCAN_UNKNOWNS`, radians and pixels; ``None`` for an Appendix C
    fit, which has none).

    Raises:
        SeaiceError: naming the key that is missing or of another ``format``.
    """
    if document.get("format") != JSON_FORMAT:
        raise SeaiceError(f"not a seaice rectify document of format {JSON_FORMAT!r} (its format: "
                          f"{document.get('format')!r})")
    try:
        stored = document["model"]
        unknowns, orbit = stored["unknowns"], stored["orbit"]
        scale = _json_scale()
        model = ScanModel(
            **{u: unknowns[_json_key(u)] / s for u, s in zip(SCAN_UNKNOWNS, scale, strict=True)},
            orbit=Orbit(np.radians(orbit["inclination_deg"]), orbit["period_s"], orbit["altitude_m"],
                        orbit["earth_day_s"], orbit["radius_m"]),
            direction=stored["direction"], n_pixels=int(stored["n_pixels"]), n_scans=int(stored["n_scans"]))
    except KeyError as error:
        raise SeaiceError(f"seaice rectify document: no {error.args[0]!r} in its model") from None
    covariance = None
    if "covariance" in stored:
        covariance = np.asarray(stored["covariance"], float) / (scale[:, None] * scale[None, :])
    return model, covariance


def orbit_fit_json(fit: OrbitFit, check_errors: dict[str, float] | None = None) -> dict:
    """The orbit-fit report as JSON-ready data (keys of the ``seaice rectify --json`` output): the report's numbers,
    the model with what rebuilds it and its covariance (``model``: :func:`scan_model_from_json`), the package
    ``version``, the document's ``format`` and the ``units`` of its numbers (:data:`JSON_UNITS`); ``check_errors``:
    ``{check point id: ground error, km}`` (:func:`~seaice_jax.adjust.orbit.fit.check_point_errors`), ``None``: no
    check points. Formats only: every number comes from ``fit`` and ``check_errors``."""
    dlat, dlon = fit.dlat_arcmin, fit.dlon_arcmin
    flag_1985, flag_w = fit.flagged_1985, fit.flagged_w_test()
    dev_lat, dev_lon = fit.dev_arcmin
    adjustment = fit.adjustment
    result = {
        "format": JSON_FORMAT,
        "version": __version__,
        "units": JSON_UNITS,
        "model": _model_json(fit),
        "parameters": _parameters(fit),
        "parameter_sigma": _parameter_sigma(fit),
        "method": fit.method,
        "iterations": fit.iterations,
        "alternatives_rms_km": fit.alternatives,
        "dev_lat_arcmin": dev_lat,
        "dev_lon_arcmin": dev_lon,
        "rms_km": fit.rms_km,
        "sigma0": None if adjustment is None or adjustment.degrees_of_freedom == 0 else float(adjustment.sigma0),
        "degrees_of_freedom": None if adjustment is None else adjustment.degrees_of_freedom,
        "stations": [
            {"id": point_id, "dlat_arcmin": float(a), "dlon_arcmin": float(b), "error_km": float(e),
             "flagged": bool(f1 or f2), "flagged_1985": bool(f1), "flagged_w_test": bool(f2)}
            for point_id, a, b, e, f1, f2 in zip(fit.control.ids, dlat, dlon, fit.error_km, flag_1985, flag_w,
                                                 strict=True)
        ],
    }
    if check_errors is not None:
        errors = np.array(list(check_errors.values()), float)
        result["check_rmse_km"] = float(np.sqrt(np.mean(errors**2)))
        result["check"] = [{"id": i, "error_km": float(e)} for i, e in check_errors.items()]
    return result


def orbit_fit_report(fit: OrbitFit, check_errors: dict[str, float] | None = None, names=None) -> str:
    """The orbit-fit report in the layout of the 1985 line-printer output (source 001, Figure 3-3).

    Adds what the 1985 program could not give: parameter standard deviations, σ̂0 and the global test, w-tests
    with data-snooping flags, RMS ground distance, and check points reported separately.
    """
    data = orbit_fit_json(fit, check_errors)
    p, model, orbit = data["parameters"], fit.model, fit.model.orbit
    names = names or {}
    direction = "SOUTHWARD" if model.direction == "south" else "NORTHWARD"
    lines = []
    if len(fit.alternatives) > 1:
        others = ", ".join(f"{d.upper()}WARD {rms:.3f} KM" for d, rms in fit.alternatives.items())
        lines.append(f"DIRECTION OF ORBIT CHOSEN AS {direction} (RMS {others})")
    else:
        lines.append(f"DIRECTION OF ORBIT ASSUMED TO BE {direction}")
    lines += [
        "",
        f" ORBITAL ANGLE    {p['orbital_angle_first_deg']:7.2f} TO {p['orbital_angle_last_deg']:7.2f}  ANGLE = "
        f"{abs(p['orbital_angle_last_deg'] - p['orbital_angle_first_deg']):.4f}",
        f" SCAN LINE        {1:7d} TO {model.n_scans:7d}",
        f" SCAN OFFSET      {p['scanner_angle_first_deg']:7.2f} TO {p['scanner_angle_last_deg']:7.2f}  OFFSET = "
        f"{p['scanner_angle_first_deg'] - p['scanner_angle_last_deg']:.4f}",
        f" PIXEL            {1:7d} TO {model.n_pixels:7d}",
        f" SUBTRACK PIXEL   {p['subtrack_pixel']:7.2f}",
        f" ASCENDING NODE   {p['ascending_node_deg']:7.2f}",
        f" ALTITUDE         {float(orbit.altitude) / 1000.0:7.2f}",
        f" ORBITAL PERIOD   {float(orbit.period) / 60.0:7.2f}",
        f" ORB MAX LATITUDE {float(np.degrees(orbit.max_latitude)):7.2f}",
        "",
        f"{'REFERENCE STATION':<28}{'PIXEL':>7}{'SCAN':>7}{'LAT':>10}{'LONG':>11}{'DLAT':>9}{'DLONG':>9}"
        f"{'W-LAT':>7}{'W-LON':>7}  FLAG",
    ]
    w_lat, w_lon = fit.w_statistics()
    for k, station in enumerate(data["stations"]):
        label = f"{station['id']:<6}{names.get(station['id'], '')[:21]:<22}"
        flag = "*" if station["flagged_1985"] else ""
        flag += "W" if station["flagged_w_test"] else ""
        lines.append(
            f"{label}{float(fit.control.pixel[k]):7.0f}{float(fit.control.scan[k]):7.0f}"
            f"{_degrees_minutes(float(np.degrees(fit.control.latitude[k]))):>10}"
            f"{_degrees_minutes(float(np.degrees(fit.control.longitude[k]))):>11}"
            f"{station['dlat_arcmin']:9.4f}{station['dlon_arcmin']:9.4f}{w_lat[k]:7.2f}{w_lon[k]:7.2f}  {flag}")
    lines.append(f"{'DEV':>63}{data['dev_lat_arcmin']:9.4f}{data['dev_lon_arcmin']:9.4f}")
    lines += ["", f"RMS GROUND DISTANCE AT THE STATIONS {data['rms_km']:.3f} KM"]
    if fit.adjustment is not None:
        dof, tested = fit.adjustment.degrees_of_freedom, fit.global_test()
        if tested is not None:
            p_value, accepted = tested
            verdict = ("ACCEPTED" if accepted else "REJECTED: the control points disagree beyond their sigma"
                       if float(fit.adjustment.sigma0) > 1 else "REJECTED: the control points agree better than their "
                       "sigma says (the sigma are pessimistic)")
            lines.append(f"SIGMA0 {data['sigma0']:.3f} WITH {dof} DEGREES OF FREEDOM, GLOBAL TEST p = "
                         f"{p_value:.3f} {verdict}")
        else:
            lines.append("NO REDUNDANCY (as many unknowns as observations): SIGMA0 AND TESTS UNAVAILABLE")
        sigma = data["parameter_sigma"]
        lines.append("STANDARD DEVIATIONS (A PRIORI): " + ", ".join(
            f"{k.removesuffix('_deg')} {v:.4g}{'°' if k.endswith('_deg') else ' px'}" for k, v in sigma.items()))
    lines.append(f"METHOD {fit.method}, {fit.iterations} "
                 f"{'ITERATIONS' if fit.method == 'gauss-newton' else 'POSITION EVALUATIONS'}")
    lines.append("FLAGS: * beyond 3 arc minutes (the 1985 rule), W rejected by the w-test (alpha 0.001)")
    if check_errors is not None:
        lines += ["", f"CHECK POINTS (not used in the fit): RMSE {data['check_rmse_km']:.3f} KM"]
        lines += [f"  {c['id']:<8}{c['error_km']:8.3f} KM" for c in data["check"]]
    return "\n".join(lines)
