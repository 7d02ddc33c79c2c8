"""The recorder process: the daemon's own recordings, written beside the loop."""
