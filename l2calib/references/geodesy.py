"""WGS-84 geodetic coordinates ↔ a local East-North-Up frame.

The conversion is exact (geodetic → ECEF → rotation into the tangent plane at the origin, no
flat-earth approximation), done by ``pymap3d`` (pure Python, vectorised with numpy, BSD-2); this
module only fixes the conventions: degrees, heights above the WGS-84 ellipsoid (as
``sensor_msgs/NavSatFix.altitude``), and one origin per reference.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from l2calib.errors import DataError


@dataclass(frozen=True)
class LocalEnu:
    """A local ENU frame at ``(lat0_deg, lon0_deg, h0_m)`` (WGS-84, ellipsoidal height)."""

    lat0_deg: float
    lon0_deg: float
    h0_m: float

    def __post_init__(self) -> None:
        if not (-90.0 <= self.lat0_deg <= 90.0 and -180.0 <= self.lon0_deg <= 360.0):
            raise DataError(
                f"ENU origin ({self.lat0_deg}, {self.lon0_deg}) is not a latitude/longitude in "
                "degrees",
                fix="give reference.options.origin as [lat_deg, lon_deg, height_m]",
            )

    def to_enu(self, lat_deg: np.ndarray, lon_deg: np.ndarray, h_m: np.ndarray) -> np.ndarray:
        """``[N, 3]`` east, north, up (m) of geodetic points."""
        import pymap3d

        e, n, u = pymap3d.geodetic2enu(
            np.asarray(lat_deg, np.float64),
            np.asarray(lon_deg, np.float64),
            np.asarray(h_m, np.float64),
            self.lat0_deg,
            self.lon0_deg,
            self.h0_m,
            deg=True,
        )
        return np.stack([np.asarray(e), np.asarray(n), np.asarray(u)], axis=-1).reshape(-1, 3)

    def to_geodetic(self, enu_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Latitude (deg), longitude (deg), ellipsoidal height (m) of ``[N, 3]`` ENU points."""
        import pymap3d

        enu = np.asarray(enu_m, np.float64).reshape(-1, 3)
        lat, lon, h = pymap3d.enu2geodetic(
            enu[:, 0], enu[:, 1], enu[:, 2], self.lat0_deg, self.lon0_deg, self.h0_m, deg=True
        )
        return np.asarray(lat), np.asarray(lon), np.asarray(h)
