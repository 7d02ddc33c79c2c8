"""What the loop is made of, built before it runs (by :mod:`daemon.assembly`): the joints'
command interfaces, the controllers' context, the safety supervisor, the starting and
fallback controllers, the tracking guard and the known load's feed-forward. The cycle takes
them finished, so building any of them (a controller's design, a plugin's import) never
happens in a cycle."""
from __future__ import annotations

from dataclasses import dataclass, field

from controllers.base import Controller, ControllerContext
from controllers.directory import Directories
from daemon.loop.feed_forward import LoadFeedForward
from daemon.loop.safety import Supervisor
from daemon.loop.tracking import TrackingGuard
from hal.actuation import RigActuation


@dataclass
class LoopParts:
    actuation: RigActuation  # the joints' command interfaces
    context: ControllerContext  # what every controller is built on (its dt is the loop's period [s])
    supervisor: Supervisor
    controller: Controller  # active at start
    fallback: Controller | None  # copied in when tracking is lost (safety.tracking_action = "fallback") or a
    # step is over its budget ([timing] policy = "hold"); built beforehand: a fallback never builds in a cycle
    tracking: TrackingGuard
    feed_forward: LoadFeedForward  # a known payload's V_MV, none at first
    controller_plugins: dict[str, str]  # name -> module:Class, from the daemon's configuration
    controller_dirs: Directories = field(default_factory=Directories)  # --controller-dir's files
