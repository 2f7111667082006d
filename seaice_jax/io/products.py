"""Products other tools read: remapped images as GeoTIFF, drift and deformation as CF-NetCDF, trajectories and
fixes as GeoJSON (one geometry type per file). Every file is written atomically
(:func:`~seaice_jax.files.atomic_path`).

The project's drift file (:func:`write_drift_netcdf`, CF 1.8 and ACDD 1.3): displacements ``dX``, ``dY`` in metres
along the grid's x and y axes (``standard_name`` ``sea_ice_x_displacement`` / ``sea_ice_y_displacement``), their
standard errors linked by ``ancillary_variables``, start and end latitude/longitude, ``time_bnds``, a ``crs``
grid-mapping variable (CF attributes and ``crs_wkt`` from pyproj) and a ``status_flag``; velocities both along the
grid axes (``u_grid``, ``v_grid``) and toward geographic east and north (``u_east``, ``v_north``); from tracking,
also each vector's tracking σ (``dX_tracking_uncertainty``, ``dY_tracking_uncertainty``) and peak ``correlation``.
:func:`write_osisaf_drift` writes the same vectors in the layout of the OSI SAF low-resolution drift product
(OSI-405: km, ``uncert_dX_and_dY``, ``dt0``/``dt1``, its flag codes). Written with xarray/netCDF4 and tifffile.
"""

import os
import warnings
from pathlib import Path

import numpy as np

from seaice_jax.errors import SeaiceError
from seaice_jax.files import atomic_path, write_geojson
from seaice_jax.geometry.projections import MapGrid
from seaice_jax.imagery.tracking import (
    AT_EDGE,
    FLAT_PEAK,
    GOOD,
    LOW_CONTRAST,
    LOW_CORRELATION,
    MIXED_MOTION,
    NO_DATA,
    ON_LAND,
    OUTLIER,
)

# ---------------------------------------------------------------------------------------------- GeoTIFF

_MODEL_PIXEL_SCALE, _MODEL_TIEPOINT, _GEO_KEYS, _GEO_DOUBLES, _GEO_ASCII = 33550, 33922, 34735, 34736, 34737
_GDAL_METADATA = 42112
_USER_DEFINED = 32767

# GeoTIFF 1.1 coordinate transformation code and (GeoKey, PROJ parameter, default) of each projection kind written
# with a user-defined projected system (the projections without EPSG code), as GDAL reads them.
_FALSE = ((3082, "x_0", 0.0), (3083, "y_0", 0.0))
_TRANSFORMS = {
    "eqc": (17, ((3089, "lat_0", 0.0), (3088, "lon_0", 0.0), (3078, "lat_ts", 0.0), *_FALSE)),
    "ortho": (21, ((3089, "lat_0", 0.0), (3088, "lon_0", 0.0), *_FALSE)),
    "laea": (10, ((3089, "lat_0", 0.0), (3088, "lon_0", 0.0), *_FALSE)),
    "stere": (15, ((3081, "lat_ts", 90.0), (3095, "lon_0", 0.0), (3092, "k_0", 1.0), *_FALSE)),
    "lcc": (8, ((3078, "lat_1", 0.0), (3079, "lat_2", 0.0), (3085, "lat_0", 0.0), (3084, "lon_0", 0.0),
                (3086, "x_0", 0.0), (3087, "y_0", 0.0))),
}


def _user_defined_keys(grid: MapGrid, path) -> tuple[list, list]:
    """GeoKeys ``(key, location, count, value)`` and GeoDoubleParams of a user-defined projected system: the
    ellipsoid (semi-axes) and the projection's coordinate transformation and parameters (degrees, metres)."""
    import warnings

    import pyproj

    crs = pyproj.CRS.from_proj4(grid.projection.proj_string())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # "you will likely lose ... information": the PROJ form is wanted
        parameters = crs.to_dict()
    if parameters.get("proj") not in _TRANSFORMS:
        raise SeaiceError(f"{path}: GeoTIFF georeferencing of {grid.projection.proj_string()!r} is not supported")
    transform, names = _TRANSFORMS[parameters["proj"]]
    ellipsoid = crs.ellipsoid
    if ellipsoid is None:
        raise SeaiceError(f"{path}: {grid.projection.proj_string()!r} has no ellipsoid")
    doubles = [ellipsoid.semi_major_metre, ellipsoid.semi_minor_metre]
    keys = [(2048, 0, 1, _USER_DEFINED), (2050, 0, 1, _USER_DEFINED), (2054, 0, 1, 9102),
            (2056, 0, 1, _USER_DEFINED), (2057, _GEO_DOUBLES, 1, 0), (2058, _GEO_DOUBLES, 1, 1),
            (3072, 0, 1, _USER_DEFINED), (3074, 0, 1, _USER_DEFINED), (3075, 0, 1, transform), (3076, 0, 1, 9001)]
    for key, name, default in names:
        keys.append((key, _GEO_DOUBLES, 1, len(doubles)))
        doubles.append(float(parameters.get(name, default)))
    return sorted(keys), doubles


ACQUISITION_TIME = "ACQUISITION_TIME"
"""The GDAL metadata item (``rasterio``'s ``tags()``, ``gdalinfo``'s Metadata) holding a GeoTIFF's acquisition time,
ISO 8601 UTC."""


def _iso(moment) -> str:
    """ISO 8601 UTC of an aware datetime, with its sub-second digits when it has any."""
    return moment.isoformat(timespec="microseconds" if moment.microsecond else "seconds").replace("+00:00", "Z")


def _acquisition_time(time: str, path) -> tuple[str, str]:
    """``(TIFF DateTime "YYYY:MM:DD HH:MM:SS", ISO 8601 UTC)`` of an ISO 8601 time; sub-second digits are kept in the
    ISO form only (the TIFF tag has whole seconds)."""
    from seaice_jax.timefmt import parse_time

    try:
        moment = parse_time(time)
    except (ValueError, AttributeError):
        raise SeaiceError(f"{path}: acquisition time {time!r} is not an ISO 8601 date-time") from None
    return moment.strftime("%Y:%m:%d %H:%M:%S"), _iso(moment)


def write_geotiff(path: str | os.PathLike, image, grid: MapGrid, description: str = "",
                  time: str | None = None) -> Path:
    """Write a remapped image ``(n_rows, n_columns)`` (float32, NaN = no data) as a GeoTIFF of ``grid``.

    Georeferencing: ModelPixelScale and ModelTiepoint (pixel-is-area, the top-left corner), GeoKeys with the
    EPSG code of the NSIDC grids or, for other projections, a user-defined projected system (ellipsoid, coordinate
    transformation and its parameters, read as such by GDAL) whose citation is the PROJ string.

    Args:
        description: the TIFF ImageDescription (GDAL: ``TIFFTAG_IMAGEDESCRIPTION``).
        time: the image's acquisition time, ISO 8601 (UTC unless an offset is given): written as the TIFF
            DateTime tag (whole seconds, UTC; GDAL: ``TIFFTAG_DATETIME``, what :func:`read_geotiff` and ``seaice
            track`` read from GeoTIFFs made by other tools) and in full as the GDAL metadata item
            :data:`ACQUISITION_TIME`. ``None``: neither.

    Raises:
        SeaiceError: naming the file, for an image not of the grid's shape, a time that is not ISO 8601, or a
            projection GeoTIFF cannot describe.
    """
    import tifffile

    image = np.asarray(image, np.float32)
    if image.shape != grid.shape:
        raise SeaiceError(f"{path}: image shape {image.shape} is not the grid's {grid.shape}")
    stamp, iso = _acquisition_time(time, path) if time is not None else (None, None)
    width, height = float(grid.pixel_width), float(grid.pixel_height)
    left, top = float(grid.x_first) - 0.5 * width, float(grid.y_first) + 0.5 * height
    code = grid.projection.epsg_code()
    citation = grid.projection.proj_string() + "|"
    # GeoKeyDirectory: version 1.1.0; GTModelType projected; GTRasterType pixel-is-area; the projected system
    keys, doubles = [(1024, 0, 1, 1), (1025, 0, 1, 1)], []
    if code is not None:
        keys.append((3072, 0, 1, code))
    else:
        user_keys, doubles = _user_defined_keys(grid, path)
        keys += [(1026, _GEO_ASCII, len(citation), 0), *user_keys]
    directory = [1, 1, 0, len(keys)] + [v for key in keys for v in key]
    extratags = [(_MODEL_PIXEL_SCALE, "d", 3, (width, height, 0.0), False),
                 (_MODEL_TIEPOINT, "d", 6, (0.0, 0.0, 0.0, left, top, 0.0), False),
                 (_GEO_KEYS, "H", len(directory), directory, False),
                 (42113, "s", 0, "nan", False)]  # GDAL_NODATA
    if iso is not None:
        extratags.append((_GDAL_METADATA, "s", 0, f'<GDALMetadata>\n  <Item name="{ACQUISITION_TIME}">{iso}</Item>\n'
                                                   "</GDALMetadata>", False))
    if code is None:
        extratags += [(_GEO_DOUBLES, "d", len(doubles), tuple(doubles), False),
                      (_GEO_ASCII, "s", 0, citation, False)]
    with atomic_path(path) as temporary:
        tifffile.imwrite(temporary, image, description=description or None, datetime=stamp, extratags=extratags,
                         metadata=None)
    return Path(path)


def _tiff_time(text: str | None) -> str | None:
    """The TIFF ``DateTime`` tag (``YYYY:MM:DD HH:MM:SS``) as ISO 8601 UTC, or None."""
    if not text:
        return None
    date, _, clock = text.strip().partition(" ")
    return f"{date.replace(':', '-')}T{clock or '00:00:00'}Z"


def _geotiff_time(tags: dict) -> str | None:
    """The acquisition time (ISO 8601 UTC) of a GeoTIFF's GDAL tags: :data:`ACQUISITION_TIME` when it is an ISO 8601
    date-time, else the TIFF ``DateTime`` tag, else None."""
    from seaice_jax.timefmt import parse_time

    text = tags.get(ACQUISITION_TIME)
    if text:
        try:
            moment = parse_time(text)
        except ValueError:
            pass
        else:
            return _iso(moment)
    return _tiff_time(tags.get("TIFFTAG_DATETIME"))


def read_geotiff(path: str | os.PathLike) -> tuple[np.ndarray, MapGrid, str | None]:
    """A single-band GeoTIFF made by any tool (GDAL, rasterio, QGIS, ``seaice remap``), read with rasterio.

    Returns:
        ``(values, grid, time)``: ``(n_rows, n_columns)`` float64 (NaN where no data), the :class:`MapGrid` of its
        CRS (:func:`~seaice_jax.geometry.crs.projection_from_definition`) and geotransform, and its acquisition
        time as ISO 8601 UTC: the GDAL metadata item :data:`ACQUISITION_TIME` (what :func:`write_geotiff` writes),
        else the TIFF ``DateTime`` tag (None without either).

    Raises:
        SeaiceError: naming the file, when it is missing, not a GeoTIFF, has no projected CRS in metres, or is
            rotated or sheared (a north-up grid is needed).
    """
    import rasterio
    from rasterio.errors import NotGeoreferencedWarning, RasterioIOError

    from seaice_jax.geometry.crs import projection_from_definition

    path = Path(path)
    if not path.is_file():
        raise SeaiceError(f"{path}: file not found")
    try:
        with warnings.catch_warnings():  # a file without a geotransform is refused below, naming it
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            opened = rasterio.open(path)
        with opened as source:
            if source.driver != "GTiff":  # e.g. a drift NetCDF of `seaice track`: no band 1 to read
                raise SeaiceError(f"{path}: not a GeoTIFF (GDAL reads it as {source.driver}); give single-band "
                                  "GeoTIFF images or the folder of `seaice remap`")
            crs, transform, tags = source.crs, source.transform, source.tags()
            bands = source.count
            if bands != 1:
                raise SeaiceError(f"{path}: {bands} bands; a single-band image is needed")
            values = source.read(1).astype(float)
            nodata = source.nodata
    except RasterioIOError as error:
        raise SeaiceError(f"{path}: not a readable GeoTIFF ({error})") from None
    if bands != 1:
        raise SeaiceError(f"{path}: {bands} bands; a single-band image is needed")
    if crs is None:
        raise SeaiceError(f"{path}: no coordinate reference system (GeoKeys)")
    if transform.b != 0 or transform.d != 0 or transform.a <= 0 or transform.e >= 0:
        raise SeaiceError(f"{path}: geotransform {tuple(transform)[:6]} is rotated, sheared or flipped; a north-up "
                          "grid is needed")
    code = crs.to_epsg()
    try:
        projection = projection_from_definition(f"EPSG:{code}" if code is not None else crs.to_wkt())
    except SeaiceError as error:
        raise SeaiceError(f"{path}: {error}") from None
    if nodata is not None and np.isfinite(nodata):
        values[values == nodata] = np.nan
    grid = MapGrid(projection, transform.c + 0.5 * transform.a, transform.f + 0.5 * transform.e, transform.a,
                   -transform.e, values.shape[0], values.shape[1])
    return values, grid, _geotiff_time(tags)


# --------------------------------------------------------------------------------------------- NetCDF

CONVENTIONS = "CF-1.8, ACDD-1.3"
"""The conventions the drift files declare: CF 1.8 (the newest version the CF checker 4.1 and the IOOS compliance
checker both know) and the Attribute Convention for Data Discovery 1.3."""

OSISAF_STATUS = {0: "missing_input_data", 1: "over_land", 2: "no_ice", 3: "close_to_coast_or_edge",
                 4: "summer_period", 10: "processing_failed", 11: "too_low_correlation", 12: "not_enough_neighbours",
                 13: "filtered_by_neighbours", 20: "smaller_pattern", 21: "corrected_by_neighbours",
                 22: "interpolated", 30: "nominal_quality"}
"""``status_flag`` codes of the OSI SAF low-resolution sea-ice drift product (OSI-405), as its files declare them."""

TO_OSISAF_STATUS = {GOOD: 30, NO_DATA: 0, LOW_CONTRAST: 10, LOW_CORRELATION: 11, FLAT_PEAK: 10, AT_EDGE: 10,
                    OUTLIER: 13, ON_LAND: 1, MIXED_MOTION: 3}
"""The OSI SAF code of each :data:`seaice_jax.imagery.tracking.STATUS` code: a patch without texture, a flat peak
and a peak at the search window's edge are all "processing_failed" there; a patch across two motions (land in it,
or its surroundings disagree: the fast-ice edge) is "close_to_coast_or_edge"."""

_FLOAT_FILL = -1e10  # OSI SAF's _FillValue of its floating-point fields


def _time_attrs(epoch: str) -> dict:
    return {"units": f"seconds since {epoch.replace('T', ' ').replace('Z', '')}", "calendar": "standard"}


def _package_version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("seaice_jax")
    except PackageNotFoundError:
        return "unknown"


def _discovery_attrs(title: str, summary: str, epoch: str, start_time: float, end_time: float, lat, lon) -> dict:
    """ACDD 1.3 global attributes (the highly recommended ones and the basic recommended ones); times in s since
    ``epoch``."""
    from datetime import UTC, datetime

    from seaice_jax.timefmt import time_after

    start, end = time_after(epoch, start_time), time_after(epoch, end_time)
    duration = f"PT{end_time - start_time:g}S"
    created = datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
    version = _package_version()
    return {"Conventions": CONVENTIONS, "title": title, "summary": summary,
            "keywords": "sea ice, sea ice motion, ice drift, ice deformation, image tracking",
            "history": f"{created} created by seaice_jax {version}", "date_created": created,
            "time_coverage_start": start, "time_coverage_end": end, "time_coverage_duration": duration,
            "product_version": version,
            "institution": "not stated (set by the producer)", "source": f"seaice_jax {version}, image tracking",
            "references": "https://cfconventions.org/; https://wiki.esipfed.org/Attribute_Convention_for_Data_Discovery_1-3",
            **geographic_bounds(lat, lon), "geospatial_lat_units": "degrees_north",
            "geospatial_lon_units": "degrees_east"}


def geographic_bounds(lat, lon) -> dict:
    """ACDD 1.3 ``geospatial_lat/lon_min/max`` (degrees) of points: the smallest longitude interval holding them
    all, with ``geospatial_lon_min > geospatial_lon_max`` where it crosses ±180°; points around a pole (no gap of
    180° or more between their longitudes: the pole lies within their convex hull on a polar map) take every
    longitude and the pole's latitude."""
    lat, lon = (np.asarray(a, float).ravel() for a in (lat, lon))
    keep = np.isfinite(lat) & np.isfinite(lon)
    lat, lon = lat[keep], lon[keep]
    # into [-180, 180), leaving longitudes already there bit for bit (the bounds are the data's own values)
    lon = np.sort(np.where((lon < -180.0) | (lon >= 180.0), (lon + 180.0) % 360.0 - 180.0, lon))
    gaps = np.diff(np.append(lon, lon[0] + 360.0))
    k = int(np.argmax(gaps))
    south, north = float(lat.min()), float(lat.max())
    if gaps[k] < 180.0:
        west, east = -180.0, 180.0
        south, north = (south, 90.0) if np.mean(lat) > 0 else (-90.0, north)
    else:
        west, east = float(lon[(k + 1) % lon.size]), float(lon[k])
    return {"geospatial_lat_min": south, "geospatial_lat_max": north, "geospatial_lon_min": west,
            "geospatial_lon_max": east}


def _grid_mapping(grid: MapGrid) -> dict:
    """The CF grid-mapping attributes and ``crs_wkt`` only (no non-standard ``proj4_params``/``epsg_code``)."""
    return {**grid.projection.cf_parameters(), "crs_wkt": grid.projection.cf_grid_mapping()["crs_wkt"]}


def _check_fields(path, grid: MapGrid, fields: dict, start_time: float, end_time: float) -> None:
    if not end_time > start_time:
        raise SeaiceError(f"{path}: end time {end_time} s must be after start time {start_time} s")
    for name in ("dX", "dY", "dX_uncertainty", "dY_uncertainty", "status_flag"):
        if name not in fields:
            raise SeaiceError(f"{path}: field {name!r} missing")
        if np.shape(fields[name]) != grid.shape:
            raise SeaiceError(f"{path}: field {name!r} has shape {np.shape(fields[name])}, grid is {grid.shape}")


def _positions(grid: MapGrid, fields: dict):
    """Grid ``x, y`` (m), start and end latitude and longitude (degrees) of every vector."""
    x, y = (np.asarray(a) for a in grid.xy())
    lat, lon = (np.degrees(np.asarray(a)) for a in grid.projection.inverse(x, y))
    dx, dy = (np.asarray(fields[k], float) for k in ("dX", "dY"))
    lat1, lon1 = (np.degrees(np.asarray(a)) for a in grid.projection.inverse(x + dx, y + dy))
    return x, y, lat, lon, lat1, lon1


def _coords(x, y, start_time: float, epoch: str) -> dict:
    return {"time": ("time", [start_time], {**_time_attrs(epoch), "standard_name": "time", "bounds": "time_bnds",
                                            "long_name": "start of the displacement interval", "axis": "T"}),
            "xc": ("xc", x[0], {"standard_name": "projection_x_coordinate", "units": "m", "axis": "X",
                                "long_name": "x coordinate of the grid", "coverage_content_type": "coordinate"}),
            "yc": ("yc", y[:, 0], {"standard_name": "projection_y_coordinate", "units": "m", "axis": "Y",
                                   "long_name": "y coordinate of the grid", "coverage_content_type": "coordinate"})}


def _lat_lon(lat, lon, dtype: type = float) -> dict:
    return {"lat": (("yc", "xc"), lat.astype(dtype), {
                "standard_name": "latitude", "units": "degrees_north", "long_name": "latitude of the start position",
                "coverage_content_type": "coordinate"}),
            "lon": (("yc", "xc"), lon.astype(dtype), {
                "standard_name": "longitude", "units": "degrees_east", "long_name": "longitude of the start position",
                "coverage_content_type": "coordinate"})}


def _write(path, data: dict, coords: dict, attrs: dict, encoding: dict) -> Path:
    import xarray as xr

    dataset = xr.Dataset(data, coords=coords, attrs=attrs)
    encoding = {**{name: {"_FillValue": None} for name in ("lat", "lon", "xc", "yc", "time", "time_bnds")},
                **encoding}
    with atomic_path(path) as temporary:
        dataset.to_netcdf(temporary, encoding=encoding, engine="netcdf4")
    return Path(path)


def write_drift_netcdf(path: str | os.PathLike, grid: MapGrid, fields: dict, start_time: float, end_time: float,
                       epoch: str, flags: dict, title: str = "Sea-ice drift", deformation=None) -> Path:
    """Write gridded drift vectors as CF-NetCDF (CF 1.8, ACDD 1.3: see :data:`CONVENTIONS`).

    Args:
        grid: the grid of the vectors' *start* positions (e.g. the tracking lattice as a :class:`MapGrid`).
        fields: ``(n_rows, n_columns)`` arrays: ``dX, dY`` (m along the grid axes), ``dX_uncertainty,
            dY_uncertainty`` (m), ``status_flag`` (int, see ``flag_meanings``), and optionally ``u_east,
            v_north`` (m/s), ``dX_tracking_uncertainty, dY_tracking_uncertainty`` (m, the tracking's part of the
            standard errors) and ``correlation`` (the match's peak normalised cross-correlation, also where the
            vector was rejected). NaN where there is no vector (no match for ``correlation``).
        start_time, end_time: s since ``epoch`` (ISO 8601 UTC) of the two images.
        flags: ``{status code: meaning}`` of ``status_flag`` (e.g. :data:`seaice_jax.imagery.tracking.STATUS`).
        deformation: optional :class:`~seaice_jax.drift.kinematics.Deformation` of triangles of the grid's
            points (flattened row-major indices), written with dimension ``triangle``.
    """
    _check_fields(path, grid, fields, start_time, end_time)
    x, y, lat, lon, lat1, lon1 = _positions(grid, fields)
    dx, dy = (np.asarray(fields[k], float) for k in ("dX", "dY"))
    interval = end_time - start_time
    dims = ("time", "yc", "xc")
    geo = {"grid_mapping": "crs", "coordinates": "lat lon"}

    def var(values, content="physicalMeasurement", **attrs):
        return (dims, np.asarray(values, float)[None], {**attrs, **geo, "coverage_content_type": content})

    east = fields.get("u_east")
    tracked = "correlation" in fields
    links = " dX_tracking_uncertainty dY_tracking_uncertainty correlation" if tracked else ""
    data = {
        "crs": ((), np.int32(0), _grid_mapping(grid)),
        **_lat_lon(lat, lon),
        "time_bnds": (("time", "nv"), np.array([[start_time, end_time]]), _time_attrs(epoch)),
        "dX": var(dx, standard_name="sea_ice_x_displacement", units="m",
                  long_name="displacement along the grid's x axis",
                  ancillary_variables="dX_uncertainty status_flag" + links),
        "dY": var(dy, standard_name="sea_ice_y_displacement", units="m",
                  long_name="displacement along the grid's y axis",
                  ancillary_variables="dY_uncertainty status_flag" + links),
        "dX_uncertainty": var(fields["dX_uncertainty"], "qualityInformation", units="m",
                              standard_name="sea_ice_x_displacement standard_error",
                              long_name="standard error of dX"),
        "dY_uncertainty": var(fields["dY_uncertainty"], "qualityInformation", units="m",
                              standard_name="sea_ice_y_displacement standard_error",
                              long_name="standard error of dY"),
        "lat1": var(lat1, "coordinate", standard_name="latitude", units="degrees_north",
                    long_name="latitude of the end position"),
        "lon1": var(lon1, "coordinate", standard_name="longitude", units="degrees_east",
                    long_name="longitude of the end position"),
        "u_grid": var(dx / interval, standard_name="sea_ice_x_velocity", units="m s-1",
                      long_name="velocity along the grid's x axis (grid-relative, not eastward)"),
        "v_grid": var(dy / interval, standard_name="sea_ice_y_velocity", units="m s-1",
                      long_name="velocity along the grid's y axis (grid-relative, not northward)"),
        "status_flag": (dims, np.asarray(fields["status_flag"], np.int8)[None], {
            "standard_name": "status_flag", "long_name": "status of the displacement vector",
            "flag_values": np.array(list(flags), np.int8),
            "flag_meanings": " ".join(m.replace(" ", "_").replace(",", "") for m in flags.values()),
            "coverage_content_type": "qualityInformation", **geo}),
    }
    if east is not None:
        data["u_east"] = var(east, standard_name="eastward_sea_ice_velocity", units="m s-1",
                             long_name="velocity toward geographic east")
        data["v_north"] = var(fields["v_north"], standard_name="northward_sea_ice_velocity", units="m s-1",
                              long_name="velocity toward geographic north")
    if tracked:
        for axis in ("X", "Y"):
            data[f"d{axis}_tracking_uncertainty"] = var(
                fields[f"d{axis}_tracking_uncertainty"], "qualityInformation", units="m",
                long_name=f"standard error of d{axis} due to the image matching alone (from the correlation peak's "
                          "height and curvature, its variance scaled by how far the patches around the vector "
                          f"disagree with it; part of d{axis}_uncertainty)")
        data["correlation"] = var(fields["correlation"], "qualityInformation", units="1", valid_range=np.array(
            [-1.0, 1.0]), long_name="peak normalised cross-correlation of the matched patches")
    if deformation is not None:
        tri = ("triangle",)
        data["triangle_vertices"] = (("triangle", "vertex"), np.asarray(deformation.triangles, np.int32), {
            "long_name": "row-major indices (yc, xc) of the triangle's corners",
            "coverage_content_type": "auxiliaryInformation"})
        for name, std_name in (("divergence", "divergence_of_sea_ice_velocity"),
                               ("shear", "sea_ice_shear_rate"), ("vorticity", "sea_ice_vorticity")):
            data[name] = (tri, getattr(deformation, name), {
                "units": "s-1", "long_name": f"{name} of the triangle (CF-like name {std_name})",
                "ancillary_variables": f"{name}_uncertainty", "coverage_content_type": "physicalMeasurement"})
            data[f"{name}_uncertainty"] = (tri, getattr(deformation, f"sigma_{name}"), {
                "units": "s-1", "long_name": f"standard error of the {name}",
                "coverage_content_type": "qualityInformation"})
    attrs = _discovery_attrs(title, "Sea-ice displacement between two images by image tracking, with standard "
                             "errors, velocities and, where computed, deformation rates of triangles.",
                             epoch, start_time, end_time, lat, lon)
    return _write(path, data, _coords(x, y, start_time, epoch), attrs,
                  {"status_flag": {"_FillValue": np.int8(-1)}})


def write_osisaf_drift(path: str | os.PathLike, grid: MapGrid, fields: dict, start_time: float, end_time: float,
                       epoch: str, title: str = "Sea-ice drift (OSI SAF layout)") -> Path:
    """Write gridded drift vectors in the layout of the OSI SAF low-resolution sea-ice drift product (OSI-405).

    Variables as that product names them: ``lat, lon`` (start, degrees), ``lat1, lon1`` (end, degrees), ``dt0,
    dt1`` (s: each vector's start and end time minus the start and end of ``time_bnds``, 0 here, since each image
    has one time), ``dX, dY`` (km along the grid axes), ``uncert_dX_and_dY`` (km: one standard error for both
    components, the root mean square of the two) and ``status_flag`` with :data:`OSISAF_STATUS` codes (translated
    by :data:`TO_OSISAF_STATUS`). Floating-point fields use OSI SAF's ``_FillValue`` -1e10.
    ``dt0``/``dt1`` have no ``standard_name`` (no CF standard name fits a time offset; OSI SAF gives none either).

    Args:
        fields: as for :func:`write_drift_netcdf` (metres; ``status_flag`` in
            :data:`seaice_jax.imagery.tracking.STATUS` codes).
    """
    _check_fields(path, grid, fields, start_time, end_time)
    x, y, lat, lon, lat1, lon1 = _positions(grid, fields)
    dx, dy = (np.asarray(fields[k], float) for k in ("dX", "dY"))
    status = np.asarray(fields["status_flag"])
    unknown = sorted(set(np.unique(status).tolist()) - set(TO_OSISAF_STATUS))
    if unknown:
        raise SeaiceError(f"{path}: status codes {unknown} have no OSI SAF equivalent")
    osisaf_status = np.vectorize(TO_OSISAF_STATUS.get, otypes=[np.int8])(status)
    present = np.isfinite(dx) & np.isfinite(dy)
    sigma = np.sqrt(0.5 * (np.asarray(fields["dX_uncertainty"], float) ** 2
                           + np.asarray(fields["dY_uncertainty"], float) ** 2))
    dims = ("time", "yc", "xc")
    geo = {"grid_mapping": "crs", "coordinates": "lat lon"}
    links = "uncert_dX_and_dY status_flag dt0 dt1"

    def var(values, content="physicalMeasurement", **attrs):
        return (dims, np.where(present, values, np.nan).astype(np.float32)[None],
                {**attrs, **geo, "coverage_content_type": content})

    data = {
        "crs": ((), np.int32(0), _grid_mapping(grid)),
        **_lat_lon(lat, lon, np.float32),
        "time_bnds": (("time", "nv"), np.array([[start_time, end_time]]), _time_attrs(epoch)),
        "dt0": var(np.zeros_like(dx), "auxiliaryInformation", units="s",
                   long_name="delta time for start of displacement"),
        "lon1": var(lon1, "coordinate", standard_name="longitude", units="degrees_east",
                    long_name="longitude at the end of the displacement"),
        "lat1": var(lat1, "coordinate", standard_name="latitude", units="degrees_north",
                    long_name="latitude at the end of the displacement"),
        "dt1": var(np.zeros_like(dx), "auxiliaryInformation", units="s",
                   long_name="delta time for end of displacement"),
        "dX": var(dx / 1000.0, standard_name="sea_ice_x_displacement", units="km",
                  long_name="component of the displacement along the x axis of the grid", ancillary_variables=links),
        "dY": var(dy / 1000.0, standard_name="sea_ice_y_displacement", units="km",
                  long_name="component of the displacement along the y axis of the grid", ancillary_variables=links),
        "status_flag": (dims, osisaf_status[None], {
            "long_name": "rejection and quality level flag", "standard_name": "status_flag",
            "flag_values": np.array(list(OSISAF_STATUS), np.int8),
            "flag_meanings": " ".join(OSISAF_STATUS.values()), "coverage_content_type": "qualityInformation",
            **geo}),
        "uncert_dX_and_dY": var(sigma / 1000.0, "qualityInformation", units="km",
                                standard_name="sea_ice_x_displacement standard_error",
                                long_name="uncertainty of dX and dY (one standard error of each component)"),
    }
    attrs = _discovery_attrs(title, "Sea-ice displacement between two images by image tracking, written in the "
                             "variable layout of the OSI SAF low-resolution sea-ice drift product (OSI-405).",
                             epoch, start_time, end_time, lat, lon)
    floats = ("dt0", "lon1", "lat1", "dt1", "dX", "dY", "uncert_dX_and_dY")
    encoding = {**{name: {"_FillValue": np.float32(_FLOAT_FILL)} for name in floats},
                "status_flag": {"_FillValue": np.int8(-1)}}
    return _write(path, data, _coords(x, y, start_time, epoch), attrs, encoding)


# --------------------------------------------------------------------------------------------- GeoJSON


def _floe_fixes(floe, time):
    """``{floe: indices of its fixes in time order}`` in order of first appearance."""
    floe, time = np.asarray(floe), np.asarray(time, float)
    return {f: (k := np.nonzero(floe == f)[0])[np.argsort(time[k], kind="stable")]
            for f in dict.fromkeys(floe.tolist())}


def _lon_lat(latitude, longitude, i) -> list[float]:
    return [round(float(np.degrees(longitude[i])), 7), round(float(np.degrees(latitude[i])), 7)]


def write_trajectories_geojson(path: str | os.PathLike, floe, time, latitude, longitude, epoch: str) -> Path:
    """One LineString feature per floe seen at least twice (RFC 7946: [longitude, latitude] degrees), with its ISO
    8601 times: one geometry type in the layer (the fixes themselves: :func:`write_fixes_geojson`)."""
    from seaice_jax.timefmt import time_after

    time = np.asarray(time, float)
    features = [{"type": "Feature",
                 "geometry": {"type": "LineString", "coordinates": [_lon_lat(latitude, longitude, i) for i in k]},
                 "properties": {"floe_id": str(f), "n_fixes": int(len(k)),
                                "start_time": time_after(epoch, float(time[k[0]])),
                                "end_time": time_after(epoch, float(time[k[-1]])),
                                "times": [time_after(epoch, float(time[i])) for i in k]}}
                for f, k in _floe_fixes(floe, time).items() if len(k) > 1]
    return write_geojson(path, features)


def write_fixes_geojson(path: str | os.PathLike, floe, time, latitude, longitude, epoch: str, tracking_sigma=None,
                        correlation=None) -> Path:
    """One Point feature per fix (floe position at one time), with ``floe_id``, ISO 8601 ``time`` and the fix's
    ``sequence`` number along its floe (0 first): the point layer beside :func:`write_trajectories_geojson`. With
    ``tracking_sigma`` ``(n, 2)`` m (along the grid's x, y) and ``correlation`` ``(n,)`` of the tracked step that
    reached each fix, also ``tracking_sigma_x_m``, ``tracking_sigma_y_m`` and ``correlation`` (null where NaN: a
    floe's first fix)."""
    from seaice_jax.timefmt import time_after

    time = np.asarray(time, float)

    def number(values, i, axis=None):
        value = float(values[i] if axis is None else values[i, axis])
        return value if np.isfinite(value) else None

    def tracked(i):
        if tracking_sigma is None or correlation is None:
            return {}
        return {"tracking_sigma_x_m": number(tracking_sigma, i, 0), "tracking_sigma_y_m": number(tracking_sigma, i, 1),
                "correlation": number(correlation, i)}

    features = [{"type": "Feature", "geometry": {"type": "Point", "coordinates": _lon_lat(latitude, longitude, i)},
                 "properties": {"floe_id": str(f), "time": time_after(epoch, float(time[i])), "sequence": n,
                                **tracked(i)}}
                for f, k in _floe_fixes(floe, time).items() for n, i in enumerate(k.tolist())]
    return write_geojson(path, features)
