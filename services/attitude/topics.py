"""The keys of a radar sensor (one key, one message type; issue 17): plots, the site description, track ends."""

from __future__ import annotations

from shared import keys


def radar_key(site_id: str, sensor_id: str = "plots") -> str:
    """``fixstream/sensor/<site>/radar/<sensor>``: the site's plots (RadarPlot only: one key, one schema)."""
    return keys.sensor(site_id, "radar", sensor_id)


#: the chunk after the radar key of the site description and of the track ends (one key per message type)
SITE_CHUNK = "site"
TRACK_END_CHUNK = "track_end"


def site_key(site_id: str, sensor_id: str = "plots") -> str:
    """``fixstream/sensor/<site>/radar/<sensor>/site``: the site's RadarSite (sigmas, scan period)."""
    return f"{radar_key(site_id, sensor_id)}/{SITE_CHUNK}"


def track_end_key(site_id: str, sensor_id: str = "plots") -> str:
    """``fixstream/sensor/<site>/radar/<sensor>/track_end``: the site's TrackEnd messages."""
    return f"{radar_key(site_id, sensor_id)}/{TRACK_END_CHUNK}"
