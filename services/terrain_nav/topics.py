"""The sensor kinds (the fourth key chunk) of the streams terrain_nav reads.

They live apart from :mod:`.simulator` so that the service process does not import the simulator (and with
it SciPy's spline fitting for recorded tracks): the service needs only these names.
"""

from __future__ import annotations

#: sensor kinds of the streams the service reads: inertial samples, radio altimeter, barometer, resets
INS_KIND, RADALT_KIND, BARO_KIND, RESET_KIND = "ins", "radalt", "baro", "reset"
