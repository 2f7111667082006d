"""A satellite image sequence adjusted at once: every image's scan-model unknowns, the tie points and the control
points, with the systematic tie errors in the stated covariance."""
