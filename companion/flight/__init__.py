"""The companion's flight: fly, supervise, report."""

HEARTBEAT_WAIT_S = 15.0  # s: how long `fly` waits for the first HEARTBEAT (an autopilot still booting)
