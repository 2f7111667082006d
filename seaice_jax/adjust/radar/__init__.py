"""The radar block: SLAR strips, navigation-error splines, sweep delay and range scale adjusted with all tie and
control points at once (and the 1970s sequential method as a baseline); Sentinel-1 timing offsets."""
