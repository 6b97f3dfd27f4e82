"""Plans out to autopilots: QGroundControl ``.plan`` and MAVLink waypoint (QGC WPL 110) files."""
