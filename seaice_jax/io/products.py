"""Products other tools read: remapped images as GeoTIFF, drift and deformation as CF-NetCDF, trajectories as
GeoJSON. Every file is written atomically (:func:`~seaice_jax.files.atomic_path`).

The drift file follows the layout of the sea-ice drift products researchers already use (e.g. the OSI SAF
low-resolution drift, OSI-405): displacements ``dX``, ``dY`` in metres along the grid's x and y axes
(``standard_name`` ``sea_ice_x_displacement`` / ``sea_ice_y_displacement``), their standard errors linked by
``ancillary_variables``, start and end latitude/longitude, ``time_bnds``, a ``crs`` grid-mapping variable (CF
attributes, PROJ string and WKT from :meth:`~seaice_jax.geometry.projections.Projection.cf_grid_mapping`) and a
``status_flag``; velocities both along the grid axes (``u_grid``, ``v_grid``) and toward geographic east and north
(``u_east``, ``v_north``). Written with xarray/netCDF4 and tifffile.
"""

import os
from pathlib import Path

import numpy as np

from seaice_jax.errors import SeaiceError
from seaice_jax.files import atomic_path, write_geojson
from seaice_jax.geometry.projections import MapGrid

# ---------------------------------------------------------------------------------------------- GeoTIFF

_MODEL_PIXEL_SCALE, _MODEL_TIEPOINT, _GEO_KEYS, _GEO_DOUBLES, _GEO_ASCII = 33550, 33922, 34735, 34736, 34737


def write_geotiff(path: str | os.PathLike, image, grid: MapGrid, description: str = "") -> Path:
    """Write a remapped image ``(n_rows, n_columns)`` (float32, NaN = no data) as a GeoTIFF of ``grid``.

    Georeferencing: ModelPixelScale and ModelTiepoint (pixel-is-area, the top-left corner), GeoKeys with the
    EPSG code of the NSIDC grids or, for other projections, a user-defined projected system whose citation is the
    PROJ string (GDAL reads it as such).
    """
    import tifffile

    image = np.asarray(image, np.float32)
    if image.shape != grid.shape:
        raise SeaiceError(f"{path}: image shape {image.shape} is not the grid's {grid.shape}")
    width, height = float(grid.pixel_width), float(grid.pixel_height)
    left, top = float(grid.x_first) - 0.5 * width, float(grid.y_first) + 0.5 * height
    code = grid.projection.epsg_code()
    citation = grid.projection.proj_string() + "|"
    # GeoKeyDirectory: version 1.1.0; GTModelType projected; GTRasterType pixel-is-area; the projected system
    keys = [(1024, 0, 1, 1), (1025, 0, 1, 1)]
    if code is not None:
        keys.append((3072, 0, 1, code))
    else:
        keys += [(1026, _GEO_ASCII, len(citation), 0), (3072, 0, 1, 32767)]
    directory = [1, 1, 0, len(keys)] + [v for key in keys for v in key]
    extratags = [(_MODEL_PIXEL_SCALE, "d", 3, (width, height, 0.0), False),
                 (_MODEL_TIEPOINT, "d", 6, (0.0, 0.0, 0.0, left, top, 0.0), False),
                 (_GEO_KEYS, "H", len(directory), directory, False),
                 (42113, "s", 0, "nan", False)]  # GDAL_NODATA
    if code is None:
        extratags.append((_GEO_ASCII, "s", 0, citation, False))
    with atomic_path(path) as temporary:
        tifffile.imwrite(temporary, image, description=description or None, extratags=extratags,
                         metadata=None)
    return Path(path)


# --------------------------------------------------------------------------------------------- NetCDF


def _time_attrs(epoch: str) -> dict:
    return {"units": f"seconds since {epoch.replace('T', ' ').replace('Z', '')}", "calendar": "standard"}


def write_drift_netcdf(path: str | os.PathLike, grid: MapGrid, fields: dict, start_time: float, end_time: float,
                       epoch: str, flags: dict, title: str = "Sea-ice drift", deformation=None) -> Path:
    """Write gridded drift vectors as CF-NetCDF.

    Args:
        grid: the grid of the vectors' *start* positions (e.g. the tracking lattice as a :class:`MapGrid`).
        fields: ``(n_rows, n_columns)`` arrays: ``dX, dY`` (m along the grid axes), ``dX_uncertainty,
            dY_uncertainty`` (m), ``status_flag`` (int, see ``flag_meanings``), and optionally ``u_east,
            v_north`` (m/s). NaN where there is no vector.
        start_time, end_time: s since ``epoch`` (ISO 8601 UTC) of the two images.
        flags: ``{status code: meaning}`` of ``status_flag`` (e.g. :data:`seaice_jax.imagery.tracking.STATUS`).
        deformation: optional :class:`~seaice_jax.drift.kinematics.Deformation` of triangles of the grid's
            points (flattened row-major indices), written with dimension ``triangle``.
    """
    import xarray as xr

    if not end_time > start_time:
        raise SeaiceError(f"{path}: end time {end_time} s must be after start time {start_time} s")
    for name in ("dX", "dY", "dX_uncertainty", "dY_uncertainty", "status_flag"):
        if name not in fields:
            raise SeaiceError(f"{path}: field {name!r} missing")
        if np.shape(fields[name]) != grid.shape:
            raise SeaiceError(f"{path}: field {name!r} has shape {np.shape(fields[name])}, grid is {grid.shape}")
    x, y = (np.asarray(a) for a in grid.xy())
    lat, lon = (np.degrees(np.asarray(a)) for a in grid.projection.inverse(x, y))
    dx, dy = (np.asarray(fields[k], float) for k in ("dX", "dY"))
    lat1, lon1 = (np.degrees(np.asarray(a)) for a in grid.projection.inverse(x + dx, y + dy))
    interval = end_time - start_time
    dims = ("time", "yc", "xc")
    geo = {"grid_mapping": "crs", "coordinates": "lat lon"}

    def var(values, **attrs):
        return (dims, np.asarray(values, float)[None], {**attrs, **geo})

    east = fields.get("u_east")
    data = {
        "crs": ((), np.int32(0), grid.projection.cf_grid_mapping()),
        "lat": (("yc", "xc"), lat, {"standard_name": "latitude", "units": "degrees_north",
                                    "long_name": "latitude of the start position"}),
        "lon": (("yc", "xc"), lon, {"standard_name": "longitude", "units": "degrees_east",
                                    "long_name": "longitude of the start position"}),
        "time_bnds": (("time", "nv"), np.array([[start_time, end_time]]), _time_attrs(epoch)),
        "dX": var(dx, standard_name="sea_ice_x_displacement", units="m",
                  long_name="displacement along the grid's x axis", ancillary_variables="dX_uncertainty status_flag"),
        "dY": var(dy, standard_name="sea_ice_y_displacement", units="m",
                  long_name="displacement along the grid's y axis", ancillary_variables="dY_uncertainty status_flag"),
        "dX_uncertainty": var(fields["dX_uncertainty"], standard_name="sea_ice_x_displacement standard_error",
                              units="m"),
        "dY_uncertainty": var(fields["dY_uncertainty"], standard_name="sea_ice_y_displacement standard_error",
                              units="m"),
        "lat1": var(lat1, standard_name="latitude", units="degrees_north", long_name="latitude of the end position"),
        "lon1": var(lon1, standard_name="longitude", units="degrees_east",
                    long_name="longitude of the end position"),
        "u_grid": var(dx / interval, standard_name="sea_ice_x_velocity", units="m s-1",
                      long_name="velocity along the grid's x axis (grid-relative, not eastward)"),
        "v_grid": var(dy / interval, standard_name="sea_ice_y_velocity", units="m s-1",
                      long_name="velocity along the grid's y axis (grid-relative, not northward)"),
        "status_flag": (dims, np.asarray(fields["status_flag"], np.int8)[None], {
            "standard_name": "status_flag", "flag_values": np.array(list(flags), np.int8),
            "flag_meanings": " ".join(m.replace(" ", "_").replace(",", "") for m in flags.values()), **geo}),
    }
    if east is not None:
        data["u_east"] = var(east, standard_name="eastward_sea_ice_velocity", units="m s-1",
                             long_name="velocity toward geographic east")
        data["v_north"] = var(fields["v_north"], standard_name="northward_sea_ice_velocity", units="m s-1",
                              long_name="velocity toward geographic north")
    if deformation is not None:
        tri = ("triangle",)
        data["triangle_vertices"] = (("triangle", "vertex"), np.asarray(deformation.triangles, np.int32), {
            "long_name": "row-major indices (yc, xc) of the triangle's corners"})
        for name, std_name in (("divergence", "divergence_of_sea_ice_velocity"),
                               ("shear", "sea_ice_shear_rate"), ("vorticity", "sea_ice_vorticity")):
            data[name] = (tri, getattr(deformation, name), {"units": "s-1", "long_name": name.replace("_", " "),
                                                             "comment": f"CF-like name: {std_name}",
                                                             "ancillary_variables": f"{name}_uncertainty"})
            data[f"{name}_uncertainty"] = (tri, getattr(deformation, f"sigma_{name}"),
                                           {"units": "s-1", "long_name": f"standard error of the {name}"})
    coords = {"time": ("time", [start_time], {**_time_attrs(epoch), "standard_name": "time", "bounds": "time_bnds",
                                               "long_name": "start of the displacement interval"}),
              "xc": ("xc", x[0], {"standard_name": "projection_x_coordinate", "units": "m", "axis": "X"}),
              "yc": ("yc", y[:, 0], {"standard_name": "projection_y_coordinate", "units": "m", "axis": "Y"})}
    dataset = xr.Dataset(data, coords=coords, attrs={"Conventions": "CF-1.10", "title": title,
                                                     "source": "seaice_jax", "references": "source 001 (ICE)"})
    encoding = {name: {"_FillValue": None} for name in ("lat", "lon", "xc", "yc", "time", "time_bnds")}
    with atomic_path(path) as temporary:
        dataset.to_netcdf(temporary, encoding=encoding, engine="netcdf4")
    return Path(path)


# --------------------------------------------------------------------------------------------- GeoJSON


def write_trajectories_geojson(path: str | os.PathLike, floe, time, latitude, longitude, epoch: str) -> Path:
    """One LineString feature per floe (RFC 7946: [longitude, latitude] degrees), with its ISO 8601 times."""
    from seaice_jax.timefmt import time_after

    floe, time = np.asarray(floe), np.asarray(time, float)
    features = []
    for f in dict.fromkeys(floe.tolist()):
        k = np.nonzero(floe == f)[0]
        k = k[np.argsort(time[k])]
        coordinates = [[round(float(np.degrees(longitude[i])), 7), round(float(np.degrees(latitude[i])), 7)]
                       for i in k]
        geometry = ({"type": "LineString", "coordinates": coordinates} if len(k) > 1
                    else {"type": "Point", "coordinates": coordinates[0]})
        features.append({"type": "Feature", "geometry": geometry,
                         "properties": {"floe_id": str(f), "times": [time_after(epoch, float(time[i])) for i in k]}})
    return write_geojson(path, features)
