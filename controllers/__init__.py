"""Controller plugins, reference paths and trajectories."""
