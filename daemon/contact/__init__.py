"""The array pressure sensor's process beside the loop, and the loop's read of its latest estimate."""
