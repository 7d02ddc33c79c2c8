"""A pneumad rig as an ophyd-async device, built from the daemon's ``describe`` and ``status``
(no hand-written list of joints or signals): what a Bluesky RunEngine reads and moves.

- ``rig.joints[i]`` is a ``Movable``: ``set(angle_deg)`` is the daemon's planned ``set`` of
  that joint (the others keep their set-points), and its status completes once the move has
  ended and the joint has settled; a refusal fails it with the daemon's RemoteError (code,
  message and data intact), a trip with the daemon's cause.
- Readable signals: per joint, every number ``status`` carries for it (angle [deg] hinted,
  set-point, velocity, V_MV; a muscle joint's measured pressures [Pa] and stiffness); for the
  rig, the force [N] and the state, and on a rig with an array sensor the latest contact
  estimate (``contact_cx`` ... [m, Pa, N], NaN while nothing touches). Configuration: the controller, its parameters, the rig
  file's hash and name. Each signal's source is ``pneumad://<rig>/<joint|rig>/<signal>``.
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

import numpy as np
from bluesky.protocols import Movable
from ophyd_async.core import (
    Array1D,
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
from hal import config

log = logging.getLogger(__name__)

SETTLED_DEG = 1.0  # a move has settled once within this of its target [deg] (PID's friction band: the
#                     middle joint's stiction can hold it 0.6 deg off) ...
STILL_SPREAD_DEG = 0.6  # ... its angle spread over at most this [deg] (2 deg/s over the window; judged by
#                          the angle, not by the status's velocity, a 10 Hz filtered difference of a noisy
#                          angle: a few deg/s at rest) ...
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


def _unit(field: str) -> str | None:
    """The unit a status field's name ends in (``angle_deg`` -> deg)."""
    for suffix, unit in (("_deg_s", "deg/s"), ("_deg", "deg"), ("_volts", "V"), ("_pa", "Pa"), ("_nm_deg", "N m/deg"),
                         ("_n", "N")):
        if field.endswith(suffix):
            return unit
    return None


def _signal(link: RigLink, path: tuple[str, ...], pick, sample) -> SignalR:
    """A read-only signal at ``path`` whose value is ``pick(status)``; its type from ``sample``."""
    if isinstance(sample, list):
        async def get():
            return np.array([_number(v) for v in pick(await link.status())], dtype=float)
        return SignalR(_StatusBackend(Array1D[np.float64], link.source(*path), get, _unit(path[-1])))
    if isinstance(sample, str):
        async def get():
            return pick(await link.status())
        return SignalR(_StatusBackend(str, link.source(*path), get))

    async def get():
        return _number(pick(await link.status()))
    return SignalR(_StatusBackend(float, link.source(*path), get, _unit(path[-1])))


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
    """One joint: its status fields as signals (the angle hinted), and ``set`` a planned move."""

    def __init__(self, link: RigLink, rig: "PneumadRig", index: int, fields: dict, name: str = ""):
        # the rig's move time and settling wait, not the rig itself: a Device attribute is a child
        self._link, self._move_s, self._settled, self.index = link, lambda: rig.move_s, rig.settled, index
        self.joint = link.describe["joints"][index]["name"]
        self._stopped = asyncio.Event()  # the RunEngine stopped the move in progress (a suspension)
        with self.add_children_as_readables(StandardReadableFormat.HINTED_UNCACHED_SIGNAL):
            self.angle_deg = _signal(link, (self.joint, "angle_deg"), self._field("angle_deg"), 0.0)
        with self.add_children_as_readables(StandardReadableFormat.UNCACHED_SIGNAL):
            for field, sample in fields.items():
                if field != "angle_deg" and (isinstance(sample, (int, float, list)) or sample is None):
                    setattr(self, field, _signal(link, (self.joint, field), self._field(field),
                                                 0.0 if sample is None else sample))
        super().__init__(name=name)

    def _field(self, field: str):
        return lambda status: status["joints"][self.joint].get(field)

    @AsyncStatus.wrap
    async def set(self, value: float) -> None:
        """Move this joint to ``value`` [deg] (a cubic of ``rig.move_s``, 0: a step), the others
        staying at their set-points, and wait until it has settled there. A move the arm's trip
        cuts short ends quietly once the RunEngine stops it (a suspender rewinds the plan:
        daemon.client.bluesky.suspend), else fails with the daemon's words."""
        self._stopped.clear()
        link = self._link
        status = await link.status()
        names = [j["name"] for j in link.describe["joints"]]
        targets = [status["joints"][n]["setpoint_deg"] for n in names]
        targets[self.index] = float(value)
        try:
            reply = await link.call("set", angles_deg=targets, duration_s=self._move_s())
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
        status = link.client.status()
        self.move_s = 2.0  # a joint's set: the cubic move's duration [s] (0: a step)
        self.settled_deg = SETTLED_DEG  # a move has settled within this of its target [deg]
        with self.add_children_as_readables():
            self.joints = DeviceVector({i: PneumadJoint(link, self, i, status["joints"][j["name"]])
                                        for i, j in enumerate(link.describe["joints"])})
        with self.add_children_as_readables(StandardReadableFormat.UNCACHED_SIGNAL):
            self.force_n = _signal(link, ("rig", "force_n"), lambda s: s.get("force_n"), 0.0)
            self.state = _signal(link, ("rig", "state"), lambda s: s["state"], "")
        if config.parse(link.describe["rig"]["source"], "<daemon>").contact_sensor is not None:
            link.follow_contact()
            with self.add_children_as_readables(StandardReadableFormat.UNCACHED_SIGNAL):
                for field, unit in CONTACT_SIGNALS.items():
                    setattr(self, f"contact_{field}", SignalR(_StatusBackend(
                        float, link.source("contact", field), partial(_contact, link, field), unit)))
        with self.add_children_as_readables(StandardReadableFormat.CONFIG_SIGNAL):
            self.controller = _signal(link, ("rig", "controller"), lambda s: s["controller"], "")
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

    async def settled(self, targets_deg: dict[str, float], move_s: float, stopped: asyncio.Event) -> None:
        """Return once the reference has ended and each named joint has stayed within
        ``settled_deg`` of its target for SETTLED_FOR_S, its angle spread over that time at most
        STILL_SPREAD_DEG, or once the RunEngine has ``stopped`` the move after the arm left the
        enabled state (a suspension); RuntimeError if it left it and nothing stopped the move
        within TRIP_GRACE_S (with the daemon's cause), or if it does not settle in time."""
        deadline = time.monotonic() + move_s + SETTLE_LIMIT_S
        still_since, seen = None, {}  # seen: each joint's lowest and highest angle since still_since [deg]
        while True:
            status = await self.link.call("status")
            if status["state"] != "enabled":
                if await stopped_within(stopped, TRIP_GRACE_S):
                    return
                raise RuntimeError(f"{self.link.rig_name}: the arm is {status['state']}: {status.get('cause', '')}")
            joints = status["joints"]
            angles = {n: joints[n]["angle_deg"] for n in targets_deg}
            now = time.monotonic()
            if status["reference_remaining_s"] <= 0.0 and all(abs(angles[n] - t) <= self.settled_deg
                                                              for n, t in targets_deg.items()):
                if still_since is not None:
                    seen = {n: (min(lo, angles[n]), max(hi, angles[n])) for n, (lo, hi) in seen.items()}
                if still_since is None or any(hi - lo > STILL_SPREAD_DEG for lo, hi in seen.values()):
                    still_since, seen = now, {n: (a, a) for n, a in angles.items()}  # (again) from here
                elif now - still_since >= SETTLED_FOR_S:
                    return
            else:
                still_since = None
            if now > deadline:
                where = ", ".join(f"{n} at {joints[n]['angle_deg']:.2f} deg" for n in targets_deg)
                raise RuntimeError(f"{self.link.rig_name}: not settled within {SETTLE_LIMIT_S:g} s of the move's end "
                                   f"({where}; targets {targets_deg})")
            await asyncio.sleep(POLL_S)

    def close(self) -> None:
        self.link.close()
