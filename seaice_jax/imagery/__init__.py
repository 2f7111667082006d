"""Rasters: remapping images into a map grid (VHR2/VHR3), camera-distortion correction (OPT), automatic tracking
by cross-correlation, time-lapse films (MOVIE)."""
