"""What bluesky-queueserver's worker loads (``start-re-manager --startup-module
daemon.client.bluesky.queue_startup``): one device per rig, the plans, and a RunEngine whose
runs go to Tiled.

It reads a JSON file named by ``PNEUMAD_BLUESKY_CONFIG``::

    {"rigs": {"arm":    {"command": "tcp://arm-pc:5560", "control": "tcp://arm-pc:5561",
                         "telemetry": "tcp://arm-pc:5562", "key_file": "/etc/pneumad/queue.key_secret"},
              "muscle": {"command": "tcp://muscle-pc:5560", ...}},
     "tiled": {"uri": "http://data-pc:8000", "api_key": "..."},
     "hdf5_directory": "/data/pneumad"}

Each rig becomes a device of that name (``arm``, ``muscle``) that a queue item names as its
first argument; ``hdf5_directory`` must be readable by the Tiled server (its
``readable_storage``). A rig that cannot be reached stops the worker's start with the reason.
"""
from __future__ import annotations

import json
import os

from bluesky import RunEngine
from bluesky.callbacks.tiled_writer import TiledWriter
from tiled.client import from_uri

from daemon.client.bluesky.device import PneumadRig
from daemon.client.bluesky.plans import identification, path_run, payload_dithers, step_response

__all__ = ["RE", "identification", "path_run", "payload_dithers", "step_response"]

with open(os.environ["PNEUMAD_BLUESKY_CONFIG"]) as _f:
    _config = json.load(_f)

for _name, _endpoints in _config["rigs"].items():
    globals()[_name] = PneumadRig.connect_to(_name, hdf5_directory=_config["hdf5_directory"], **_endpoints)
    __all__.append(_name)

RE = RunEngine({})
RE.subscribe(TiledWriter(from_uri(_config["tiled"]["uri"], api_key=_config["tiled"].get("api_key"))))
