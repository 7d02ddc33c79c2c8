"""Recording file formats (MCAP write and read, CSV export, numpy loading): a leaf every side
may read.

    from daemon import recordings
    data = recordings.load("run.mcap")
"""
from daemon.recordings.reading import CutRecording, export_csv, load

__all__ = ["CutRecording", "export_csv", "load"]
