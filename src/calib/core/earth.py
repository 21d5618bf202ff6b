"""WGS-84 Earth model in the local-level ENU navigation frame.

Frames and conventions used throughout ``calib``:

* ``n`` — local-level navigation frame, axes East, North, Up (ENU).
* ``b`` — body frame of the IMU; Liu 2021 uses right-front-up (x right, y front, z up).
* Latitude ``lat`` and longitude ``lon`` in radians inside the library, degrees in files and config.
* Heights in metres above the WGS-84 ellipsoid.

Constants are the WGS-84 defining and derived parameters (NIMA TR8350.2, 3rd ed., tables 3.1-3.3).
"""
from __future__ import annotations

import math

import numpy as np

#: standard gravity g0 [m/s^2]: the conventional 'g' of sensor datasheets (3rd CGPM, 1901); a unit, not the
#: local gravity (use :func:`normal_gravity` for that)
STANDARD_GRAVITY = 9.80665
#: semi-major axis a [m]
A = 6378137.0
#: flattening f [-]
F = 1.0 / 298.257223563
#: first eccentricity squared e^2 [-]
E2 = F * (2.0 - F)
#: semi-minor axis b [m]
B = A * (1.0 - F)
#: Earth rotation rate omega_ie [rad/s] (WGS-84 value used by the navigation equations)
OMEGA_IE = 7.292115e-5
#: normal gravity at the equator gamma_e [m/s^2]
GAMMA_E = 9.7803253359
#: normal gravity at the pole gamma_p [m/s^2]
GAMMA_P = 9.8321849378
#: Somigliana's constant k = (b gamma_p - a gamma_e) / (a gamma_e)
K_SOMIGLIANA = (B * GAMMA_P - A * GAMMA_E) / (A * GAMMA_E)
#: geocentric gravitational constant GM [m^3/s^2]
GM = 3.986004418e14
#: m = omega^2 a^2 b / GM
M_RATIO = OMEGA_IE**2 * A**2 * B / GM

DEG = math.pi / 180.0
#: one degree per hour in rad/s
DEG_PER_H = DEG / 3600.0


def normal_gravity(lat_rad, height_m=0.0):
    """WGS-84 normal gravity magnitude [m/s^2] at geodetic latitude ``lat_rad`` and ellipsoidal height.

    Somigliana's closed formula on the ellipsoid (TR8350.2 eq. 4-1) and the second-order free-air
    correction in height (TR8350.2 eq. 4-3). Accurate to ~1e-7 m/s^2 below 20 km.
    """
    s2 = np.sin(lat_rad) ** 2
    g0 = GAMMA_E * (1.0 + K_SOMIGLIANA * s2) / np.sqrt(1.0 - E2 * s2)
    h = height_m
    return g0 * (1.0 - 2.0 / A * (1.0 + F + M_RATIO - 2.0 * F * s2) * h + 3.0 / A**2 * h * h)


def radii(lat_rad):
    """Meridian radius R_M and transverse (prime vertical) radius R_N [m] at latitude ``lat_rad``."""
    s2 = np.sin(lat_rad) ** 2
    w = np.sqrt(1.0 - E2 * s2)
    r_n = A / w
    r_m = A * (1.0 - E2) / w**3
    return r_m, r_n


def earth_rate_enu(lat_rad):
    """Earth rotation rate omega_ie^n in the ENU frame [rad/s]: (0, Omega cos L, Omega sin L)."""
    return np.array([0.0, OMEGA_IE * math.cos(lat_rad), OMEGA_IE * math.sin(lat_rad)])


def gravity_enu(lat_rad, height_m=0.0):
    """Normal gravity vector g^n in ENU [m/s^2]: (0, 0, -gamma). Specific force at rest is +gamma up."""
    return np.array([0.0, 0.0, -float(normal_gravity(lat_rad, height_m))])


def schuler_frequency(lat_rad, height_m=0.0):
    """Schuler angular frequency omega_s = sqrt(g / R) [rad/s] with R = sqrt(R_M R_N) + h."""
    r_m, r_n = radii(lat_rad)
    return math.sqrt(float(normal_gravity(lat_rad, height_m)) / (math.sqrt(r_m * r_n) + height_m))
