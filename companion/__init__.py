"""MAVLink companion: mission upload, flight supervision and replanning (see the companion issue)."""
