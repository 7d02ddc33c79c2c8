"""What bluesky-queueserver's worker loads (``start-re-manager --startup-module
daemon.client.bluesky.queue_startup``): one device per rig, the plans, and a RunEngine whose
runs go to Tiled.

It reads a JSON file named by ``PNEUMAD_BLUESKY_CONFIG``::

    {"rigs": {"arm":    {"command": "tcp://arm-pc:5560", "control": "tcp://arm-pc:5561",
                         "telemetry": "tcp://arm-pc:5562", "key_file": "/etc/pneumad/queue.key_secret"},
              "muscle": {"command": "tcp://muscle-pc:5560", ...}},
     "tiled": {"uri": "http://data-pc:8000", "api_key": "..."},
     "hdf5_directory": "/data/pneumad", "suspend_on_trip": true}

Each rig becomes a device of that name (``arm``, ``muscle``) that a queue item names as its
first argument; ``hdf5_directory`` must be readable by the Tiled server (its
``readable_storage``). A rig that cannot be reached stops the worker's start with the reason.
With ``suspend_on_trip`` (the default) each rig's suspender is installed
(:mod:`daemon.client.bluesky.suspend`): a trip or an e-stop of any rig pauses the running plan
until that rig is reset and enabled, and the queue keeps its items meanwhile.
"""
from __future__ import annotations

import json
import os

from bluesky import RunEngine
from bluesky.callbacks.tiled_writer import TiledWriter
from tiled.client import from_uri

from daemon.client.bluesky.device import PneumadRig
from daemon.client.bluesky.plans import identification, path_run, payload_dithers, step_response
from daemon.client.bluesky.suspend import suspender

__all__ = ["RE", "identification", "path_run", "payload_dithers", "step_response"]

with open(os.environ["PNEUMAD_BLUESKY_CONFIG"]) as _f:
    _config = json.load(_f)

for _name, _endpoints in _config["rigs"].items():
    globals()[_name] = PneumadRig.connect_to(_name, hdf5_directory=_config["hdf5_directory"], **_endpoints)
    __all__.append(_name)

RE = RunEngine({})
if _config.get("suspend_on_trip", True):
    for _name in _config["rigs"]:
        RE.install_suspender(suspender(globals()[_name]))
RE.subscribe(TiledWriter(from_uri(_config["tiled"]["uri"], api_key=_config["tiled"].get("api_key"))))
