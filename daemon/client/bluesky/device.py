"""A pneumad rig as an ophyd-async device, built from the daemon's ``describe`` (its cycle
record layout: no hand-written list of joints or signals): what a Bluesky RunEngine reads and moves.

- ``rig.joints[i]`` is a ``Movable``: ``set(position)`` [the joint's display unit: deg for a
  rotary joint, mm for a linear one] is the daemon's planned ``set`` of that joint (the others
  keep their set-points), and its status completes once the move has ended and the joint has
  settled; a refusal fails it with the daemon's RemoteError (code, message and data intact),
  a trip with the daemon's cause.
- Readable signals: per joint, one per field of the cycle record it owns (``position``
  hinted, ``velocity``, ``setpoint``, ``error``, each command ``u_<command>``, commanded and
  measured pressures ``p_<chamber>_cmd`` and ``p_<chamber>``, further inputs by name, the
  shadow's ``shadow_<command>``), in the field's display unit (deg, mm, else SI), NaN where the
  record has nothing (a command outside ``enabled``); for the rig, its own sensors by name
  (``force``, ``supply_pressure`` ...) and the state, and on a rig with an array sensor the
  latest contact estimate (``contact_cx`` ... [m, Pa, N], NaN while nothing touches).
  Configuration: the controller, its parameters, the rig file's hash and name. Each signal's
  source is ``pneumad://<rig>/<joint|rig>/<field>``; values come from the latest ``state``
  message (:meth:`RigLink.follow`), the state from ``status``.
- ``stage`` takes the lease (renewed in the background) and enables the arm; ``unstage``
  hands the lease back: a run holds the arm for its length and no longer.
"""
from __future__ import annotations

import asyncio
import json
import logging
import math
import time
from functools import partial

from bluesky.protocols import Movable
from ophyd_async.core import (
    AsyncStatus,
    DeviceVector,
    SignalR,
    SoftSignalBackend,
    StandardReadable,
    StandardReadableFormat,
)

from daemon.client.bluesky.link import RigLink
from daemon.client.client import RemoteError
from daemon.wire import protocol as P
from daemon.wire.cycle_layout import Field
from hal import config

log = logging.getLogger(__name__)

SETTLED = 1.0  # a move has settled once within this of its target [deg, or mm on a linear joint] (PID's
#                friction band: the middle joint's stiction can hold it 0.6 deg off) ...
STILL_SPREAD = 0.6  # ... its position spread over at most this [deg or mm] (2 deg/s over the window; judged by
#                     the position, not by the velocity, a 10 Hz filtered difference of a noisy angle: a few
#                     deg/s at rest) ...
SETTLED_FOR_S = 0.3  # ... for this long [s]
SETTLE_LIMIT_S = 30.0  # after the reference's end, at most this long to settle [s]
POLL_S = 0.05
TRIP_GRACE_S = 2.0  # a move the arm's trip cut short fails after this [s], unless the RunEngine stopped it first
LEASE_TTL_S = 5.0  # the run's lease [s]: a RunEngine's process (plans, callbacks, a Tiled writer) is busy
#                    enough that, beside two CPU hogs, its renewals once missed the rig file's 2 s and the
#                    arm tripped mid-plan; a client that dies leaves the arm held this long before the
#                    rig file's unleased action


class _StatusBackend(SoftSignalBackend):
    """A soft signal whose value is read from the daemon on every read, named by its source."""

    def __init__(self, datatype, source: str, getter, units: str | None = None):
        super().__init__(datatype, units=units, getter=getter)
        self._source = source

    def source(self, name: str, read: bool) -> str:
        return self._source


def _number(value) -> float:
    return math.nan if value is None else float(value)


def _status_signal(link: RigLink, path: tuple[str, ...], pick) -> SignalR:
    """A read-only text signal at ``path`` whose value is ``pick(status)``."""
    async def get():
        return pick(await link.status())
    return SignalR(_StatusBackend(str, link.source(*path), get))


def _field_signal(link: RigLink, field: Field) -> SignalR:
    """The latest value of one field of the cycle record, in its display unit."""
    unit, scale = field.display
    return SignalR(_StatusBackend(float, link.source(field.owner or "rig", field.quantity),
                                  lambda: _number(link.row.get(field.name)) * scale, unit))


def attribute(field: Field) -> str:
    """A field's signal's attribute: its quantity, dots as underscores (``u.v_mv`` -> ``u_v_mv``)."""
    return field.quantity.replace(".", "_")


CONTACT_SIGNALS = {"cx": "m", "cy": "m", "a": "m", "b": "m", "p_max": "Pa", "force_n": "N", "cx_sd": "m", "cy_sd": "m",
                   "force_sd_n": "N"}  # of the contact estimate (docs/protocol.md, contact topic)


def _contact(link: RigLink, field: str) -> float:
    """``field`` of the latest contact estimate; NaN before the first, or while nothing touches."""
    message = link.contact
    estimate = message.get("contact") if message else None
    return _number(estimate.get(field)) if estimate else math.nan


async def stopped_within(stopped: asyncio.Event, seconds: float) -> bool:
    """Whether the RunEngine stops the move within ``seconds`` (a suspender acting on the same
    trip from the event topic) rather than the move failing the plan."""
    try:
        await asyncio.wait_for(stopped.wait(), seconds)
    except TimeoutError:
        return False
    return True


class PneumadJoint(StandardReadable, Movable):
    """One joint: its fields of the cycle record as signals (the position hinted), and ``set``
    a planned move."""

    def __init__(self, link: RigLink, rig: "PneumadRig", joint: str, name: str = ""):
        # the rig's move time and settling wait, not the rig itself: a Device attribute is a child
        self._link, self._move_s, self._settled, self.joint = link, lambda: rig.move_s, rig.settled, joint
        self.position_field = link.layout[f"{joint}.position"]
        self._stopped = asyncio.Event()  # the RunEngine stopped the move in progress (a suspension)
        with self.add_children_as_readables(StandardReadableFormat.HINTED_UNCACHED_SIGNAL):
            self.position = _field_signal(link, self.position_field)
        with self.add_children_as_readables(StandardReadableFormat.UNCACHED_SIGNAL):
            for field in link.layout.of_joint(joint):
                if field.quantity != "position":
                    setattr(self, attribute(field), _field_signal(link, field))
        super().__init__(name=name)

    @AsyncStatus.wrap
    async def set(self, value: float) -> None:
        """Move this joint to ``value`` [its position's display unit: deg or mm] (a cubic of
        ``rig.move_s``, 0: a step), the others staying at their set-points, and wait until it
        has settled there. A move the arm's trip cuts short ends quietly once the RunEngine
        stops it (a suspender rewinds the plan: daemon.client.bluesky.suspend), else fails with
        the daemon's words."""
        self._stopped.clear()
        link = self._link
        layout = link.layout
        joints = layout.owners()
        # each joint's set-point in its display unit, as ``set``'s positions take them (deg, mm)
        targets = [link.row[f"{j}.setpoint"] * layout[f"{j}.position"].display[1] for j in joints]
        targets[joints.index(self.joint)] = float(value)
        try:
            reply = await link.call("set", positions=targets, duration_s=self._move_s())
        except RemoteError as exc:
            if exc.code != P.BAD_STATE or not await stopped_within(self._stopped, TRIP_GRACE_S):
                raise
            return
        link.forget_status()
        await self._settled({self.joint: float(value)}, reply["duration_s"], self._stopped)

    async def stop(self, success: bool = True) -> None:
        """The RunEngine stops every moved device when it suspends a plan: a move in progress
        then ends without failing the plan (it is made again on resume)."""
        self._stopped.set()


class PneumadRig(StandardReadable):
    """The rig a daemon runs, as one device; ``PneumadRig.connect_to(...)`` builds it."""

    def __init__(self, link: RigLink, name: str = "", hdf5_directory: str = "."):
        self.link = link
        self.hdf5_directory = hdf5_directory  # where plans write the daemon's records as HDF5
        contact = config.parse(link.describe["rig"]["source"], "<daemon>").contact_sensor is not None
        link.follow(contact)  # the cycle record's layout, and its latest row from here on
        self.move_s = 2.0  # a joint's set: the cubic move's duration [s] (0: a step)
        self.settled_within = SETTLED  # a move has settled within this of its target [each joint's display unit]
        with self.add_children_as_readables():
            self.joints = DeviceVector({i: PneumadJoint(link, self, joint) for i, joint in enumerate(link.layout.owners())})
        with self.add_children_as_readables(StandardReadableFormat.UNCACHED_SIGNAL):
            for field in link.layout.of_group("measured"):
                if not field.owner:  # the rig's own sensors: force, supply_pressure ...
                    setattr(self, attribute(field), _field_signal(link, field))
            self.state = _status_signal(link, ("rig", "state"), lambda s: s["state"])
        if contact:
            with self.add_children_as_readables(StandardReadableFormat.UNCACHED_SIGNAL):
                for field, unit in CONTACT_SIGNALS.items():
                    setattr(self, f"contact_{field}", SignalR(_StatusBackend(
                        float, link.source("contact", field), partial(_contact, link, field), unit)))
        with self.add_children_as_readables(StandardReadableFormat.CONFIG_SIGNAL):
            self.controller = _status_signal(link, ("rig", "controller"), lambda s: s["controller"])
            self.controller_params = SignalR(_StatusBackend(str, link.source("rig", "controller_params"),
                                                            self._controller_params))
            self.rig_hash = SignalR(_StatusBackend(str, link.source("rig", "hash"),
                                                   lambda: link.describe["rig"]["hash"]))
            self.rig_name = SignalR(_StatusBackend(str, link.source("rig", "name"), lambda: link.rig_name))
        super().__init__(name=name)

    @classmethod
    def connect_to(cls, name: str, command: str | None = None, control: str | None = None,
                   telemetry: str | None = None, key_file: str | None = None, server_key_file: str | None = None,
                   timeout: float = 5.0, hdf5_directory: str = ".") -> "PneumadRig":
        """The device of the daemon at these endpoints (``pneumactl``'s: arguments, else the
        ``PNEUMAD_*`` variables, else the defaults), named ``name``, its plans' HDF5 files in
        ``hdf5_directory``; it reads ``describe`` now."""
        link = RigLink(command, control, telemetry, key_file, server_key_file, timeout)
        link.describe = link.client.describe()
        return cls(link, name=name, hdf5_directory=hdf5_directory)

    async def _controller_params(self) -> str:
        return json.dumps(await self.link.call("controller"), sort_keys=True, default=str)

    @AsyncStatus.wrap
    async def stage(self) -> None:
        """Take the lease for the run (renewed in the background) and enable the arm."""
        await super().stage()
        await self.take_lease()
        if (await self.link.call("status"))["state"] != "enabled":
            await self.link.call("enable")
        self.link.forget_status()

    async def take_lease(self) -> None:
        """Hold the rig's lease (renewed in the background), unless this client holds it."""
        client = self.link.client
        if client.lease is None:
            await self.link.call("acquire_lease", LEASE_TTL_S)
            client.keep_lease()

    @AsyncStatus.wrap
    async def unstage(self) -> None:
        """Hand the lease back (the rig file's unleased action applies from then on)."""
        if self.link.client.lease is not None:
            try:
                await self.link.call("release_lease")
            except RemoteError as exc:  # it lapsed (the daemon then acted on it, as the run's status says)
                if exc.code != P.NO_LEASE:
                    raise
                log.warning("%s: the lease had lapsed before the run handed it back: %s", self.link.rig_name, exc)
        await super().unstage()

    async def settled(self, targets: dict[str, float], move_s: float, stopped: asyncio.Event) -> None:
        """Return once the reference has ended and each named joint has stayed within
        ``settled_within`` of its target [its display unit] for SETTLED_FOR_S, its position
        spread over that time at most STILL_SPREAD, or once the RunEngine has ``stopped`` the
        move after the arm left the enabled state (a suspension); RuntimeError if it left it
        and nothing stopped the move within TRIP_GRACE_S (with the daemon's cause), or if it
        does not settle in time."""
        deadline = time.monotonic() + move_s + SETTLE_LIMIT_S
        layout = self.link.layout
        shown = {n: layout[f"{n}.position"] for n in targets}
        still_since, seen = None, {}  # seen: each joint's lowest and highest position since still_since
        while True:
            status = await self.link.call("status")
            if status["state"] != "enabled":
                if await stopped_within(stopped, TRIP_GRACE_S):
                    return
                raise RuntimeError(f"{self.link.rig_name}: the arm is {status['state']}: {status.get('cause', '')}")
            row = self.link.row
            here = {n: _number(row.get(f.name)) * f.display[1] for n, f in shown.items()}
            now = time.monotonic()
            if status["reference_remaining_s"] <= 0.0 and all(abs(here[n] - t) <= self.settled_within
                                                              for n, t in targets.items()):
                if still_since is not None:
                    seen = {n: (min(lo, here[n]), max(hi, here[n])) for n, (lo, hi) in seen.items()}
                if still_since is None or any(hi - lo > STILL_SPREAD for lo, hi in seen.values()):
                    still_since, seen = now, {n: (a, a) for n, a in here.items()}  # (again) from here
                elif now - still_since >= SETTLED_FOR_S:
                    return
            else:
                still_since = None
            if now > deadline:
                where = ", ".join(f"{n} at {here[n]:.2f} {f.display[0]}" for n, f in shown.items())
                raise RuntimeError(f"{self.link.rig_name}: not settled within {SETTLE_LIMIT_S:g} s of the move's end "
                                   f"({where}; targets {targets})")
            await asyncio.sleep(POLL_S)

    def close(self) -> None:
        self.link.close()
