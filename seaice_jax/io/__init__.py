"""Reading and writing files: CSV, later station files, projects, GeoJSON, NetCDF and GeoTIFF."""

from seaice_jax.io.files import atomic_path, write_csv, write_json

__all__ = ["atomic_path", "write_csv", "write_json"]
