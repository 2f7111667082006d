"""Reading and writing files: stations, radar projects, image sequences and products (CSV, GeoJSON, CF-NetCDF,
GeoTIFF); validation at the boundary. Atomic writing itself is :mod:`seaice_jax.files`."""
