"""The messenger process: the ZeroMQ sockets, CURVE guard, telemetry fan-out, PlotJuggler stream."""
