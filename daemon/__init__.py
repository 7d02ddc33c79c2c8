"""The pneumad daemon: the 1 ms loop, its safety supervisor, command server and telemetry."""
