"""The built-in scenario of ``seaice demo``: one radar strip and one satellite image over the Arctic.

* Radar: an AIDJEX-like flight (source 000): 10 km altitude, 170 m/s (~610 km/h), heading 80° near 75°N 150°W,
  right-looking L-band radar imaging from near nadir to ~70° off nadir, 10 minutes of flight.
* Satellite: the NOAA-7 image of source 001, Figure 3-3 (the printed orbit and scan parameters, T_e = 1440 min),
  with its five reference stations.
"""

from dataclasses import dataclass

import numpy as np

from seaice_jax.geometry.earth import SOLAR_DAY
from seaice_jax.geometry.range_doppler import LookSide
from seaice_jax.geometry.scan import Orbit, ScanModel
from seaice_jax.geometry.trajectory import CircularTrajectory


@dataclass(frozen=True)
class RadarStrip:
    """A radar strip: the sensor trajectory and the image grid in time and slant range.

    Attributes:
        trajectory: position/velocity as a function of time.
        times: ``(n_lines,)`` seconds of the image lines.
        slant_ranges: ``(n_samples,)`` metres of the range samples.
        look_side: ``"right"`` or ``"left"``.
    """

    trajectory: CircularTrajectory
    times: np.ndarray
    slant_ranges: np.ndarray
    look_side: LookSide


@dataclass(frozen=True)
class ReferenceStation:
    """A ground control point printed in source 001, Figure 3-3 (latitude/longitude in degrees)."""

    number: int
    name: str
    pixel: float
    scan: float
    latitude_deg: float
    longitude_deg: float
    printed_dlat_arcmin: float
    printed_dlon_arcmin: float


def demo_radar_strip() -> RadarStrip:
    """The AIDJEX-like radar strip of the demo (10 min, lines every 20 s, ranges 10.5-30 km)."""
    trajectory = CircularTrajectory.from_heading(np.radians(75.0), np.radians(-150.0), np.radians(80.0), 10_000.0,
                                                 170.0)
    return RadarStrip(trajectory, np.arange(0.0, 601.0, 20.0), np.linspace(10_500.0, 30_000.0, 14), "right")


def figure_3_3_image() -> ScanModel:
    """The scan model printed in source 001, Figure 3-3: subtrack pixel 112, OFFSET 6.9607°, orbital angle
    99.47° + 4.6088°, node 66.65°, altitude 0, period 102.03 min, maximum latitude 81.10°, southbound,
    T_e = 1440 min."""
    orbit = Orbit.from_max_latitude(np.radians(81.10), 102.03 * 60.0, 0.0, earth_day=SOLAR_DAY)
    return ScanModel(np.radians(6.9607), 112.0, np.radians(99.47), np.radians(4.6088), np.radians(66.65), orbit,
                     "south")


FIGURE_3_3_STATIONS = (
    ReferenceStation(3030, "COB IS ICE", 164, 123, 75 + 43 / 60, -(78 + 37 / 60), 0.6161, 0.0279),
    ReferenceStation(3031, "N DEV PT", 114, 172, 75 + 51 / 60, -(81 + 55 / 60), -0.4779, -0.6537),
    ReferenceStation(3032, "KKOD", 165, 400, 73 + 47 / 60, -(84 + 50 / 60), 0.3630, 0.4715),
    ReferenceStation(3034, "BYLOT E", 348, 281, 72 + 59 / 60, -(75 + 42 / 60), -0.7077, -0.6706),
    ReferenceStation(3035, "E DEV", 199, 204, 74 + 52 / 60, -(79 + 14 / 60), 0.2307, 0.5988),
)
"""The five reference stations of source 001, Figure 3-3 (DLAT, DLONG: computed minus known, arc minutes)."""
