"""The daemon's states, as every side names them (docs/protocol.md, "States"):
STARTING -> IDLE <-> ENABLED; any trip -> FAULT, an e-stop -> ESTOP (:mod:`daemon.loop.safety`)."""
from enum import Enum


class State(str, Enum):
    STARTING = "starting"
    IDLE = "idle"
    ENABLED = "enabled"
    FAULT = "fault"
    ESTOP = "estop"
