"""Physical and astronomical constants, SI units, with their sources."""

from __future__ import annotations

#: Planck constant [J s] (SI 2019 exact).
PLANCK_H = 6.62607015e-34
#: Speed of light in vacuum [m/s] (exact).
SPEED_OF_LIGHT = 299_792_458.0
#: Astronomical unit [m] (IAU 2012 Resolution B2, exact).
AU = 149_597_870_700.0
#: Nominal total solar irradiance at 1 AU [W/m^2] (IAU 2015 Resolution B3).
TSI_IAU2015 = 1361.0
#: Nominal solar photospheric radius [m] (IAU 2015 Resolution B3).
SUN_RADIUS = 6.957e8
#: Effective temperature of the Sun [K] (IAU 2015 Resolution B3).
SUN_TEFF = 5772.0
#: Mean lunar radius used as the LOLA reference sphere [m] (LOLA PDS labels).
MOON_RADIUS = 1_737_400.0
#: Seconds per Julian day.
DAY = 86_400.0

#: Angle units [rad].
DEG = 0.017453292519943295
ARCSEC = DEG / 3600.0
