"""The rig's model beside the arm, in a process of its own (docs/model.md).

The messenger hands it every ``state`` message as it leaves the loop's ring (a ZeroMQ PUSH on
a private ipc socket in the rings' directory, ``MODEL_FEED``: the messenger binds, this process
connects, as the recorder's feed), the same columns subscribers get. Here each cylinder joint's
identified model runs on the pressures the loop commanded (:mod:`controllers.drift`), a linear
axis's on the volts its valve was given (:mod:`controllers.drift_axis`); at the
rig file's ``[model_watch] publish_hz`` the residual since the last message and its window's
statistics go back to the messenger (``MODEL_OUT``) as the ``model`` topic, which it publishes,
streams to Foxglove (``/pneumad/model``) and hands to the recorder; a joint that leaves its
band (or comes back) is a ``model`` event, which the messenger publishes and writes to the
journal. The verdicts are also kept in shared memory for the ``status`` field ``model``, read
by the loop (a copy of a few numbers a joint) only when a status is asked for. Nothing of
this runs in the loop's cycle.

A message the feed drops (this process slower than the telemetry) is a gap in the cycles:
the models start again from the arm (:class:`controllers.drift_watch.ModelWatch`). It is a helper
process (:class:`hal.process.Helper`) at nice 10; if it dies the loop's port starts another
at its next look (once a second: a ``model`` event), whose models start again.
"""
from __future__ import annotations

import ctypes
import math
import signal

from hal.config import RigConfig
from hal.interfaces import LINEAR
from hal.process import Child, Helper, HelperFailed, SharedMemory
from hal.seqlock import try_read, write_locked
from daemon.wire.helper_links import EVENT, MODEL_FEED, MODEL_FEED_HWM, MODEL_OUT, MODEL_TOPIC, endpoint

CAUSES = ("", "offset", "leak_head", "leak_rod", "gain", "friction")  # a status's cause, by index (controllers.drift)
NUMBERS = ("anchored", "rms", "mean", "drift", "since_t", "cause", "size")  # a joint's status numbers (rms, mean: its unit's)


def wanted(rig: RigConfig) -> list[str]:
    """The joints a model runs beside on ``rig`` (none: no model process)."""
    if not rig.model_watch.enabled:
        return []
    from controllers.drift_watch import watched_joints
    return watched_joints(rig)


def _shared(joints: int) -> SharedMemory:
    return SharedMemory({"seq": ctypes.c_uint64, "values": ctypes.c_double * (max(joints, 1) * len(NUMBERS))})


class ModelProcess:
    """The loop's handle on the model process (started, restarted if it dies, its verdicts read)."""

    def __init__(self, rings_dir: str, rig: RigConfig, joints: list[str]):
        from controllers.drift import band_of
        self.joints, self.band_deg = joints, rig.model_watch.band_deg
        # each joint's band and where it came from (the identification's, else the rig file's), and its unit
        self.bands = {j.name: band_of(rig, j) for j in rig.joints if j.name in joints}
        self.units = {j.name: "mm" if j.kind == LINEAR else "deg" for j in rig.joints if j.name in joints}
        self._shared = _shared(len(joints))
        self._proc = Helper("daemon.model.process:serve", (rings_dir, rig, joints, self._shared),
                            name="the model process", pass_fds=(self._shared.fd,), nice=10)

    def start(self) -> None:
        self._proc.start()  # HelperFailed, in its words, if it did not start

    def check(self) -> str | None:
        """Called once a second from the loop, never blocking: a dead process is started again;
        what happened, as an event's cause."""
        code = self._proc.restart_if_dead()
        if code is None:
            try:
                self._proc.poll_ready()
            except HelperFailed:
                pass  # it exits: the next check starts another
            return None
        write_locked(self._shared.seq, self._shared.values, [math.nan] * len(self._shared.values))
        return (f"the model process exited (code {code}) and was restarted (restart {self._proc.restarts}); "
                f"its models start again from the arm")

    def status(self) -> dict:
        """The status field ``model``: per joint, whether its model runs (``anchored``), the
        residual's RMS and mean over the window and the band in force (in the joint's unit: deg
        rotary, ``_mm`` on a linear axis) and where the band came from, whether it has drifted out of it, since when [s, the loop's clock], and the likely
        cause (null: none named)."""
        found = try_read(self._shared.seq, self._shared.values, tries=200)
        values = found[1] if found is not None else [math.nan] * len(self._shared.values)
        joints = {}
        for k, name in enumerate(self.joints):
            v = dict(zip(NUMBERS, values[k * len(NUMBERS):(k + 1) * len(NUMBERS)]))
            drift = v["drift"] == 1.0
            cause = int(v["cause"]) if v["cause"] == v["cause"] else 0
            u = self.units[name]
            joints[name] = {"anchored": v["anchored"] == 1.0, f"rms_{u}": _number(v["rms"]),
                            f"mean_{u}": _number(v["mean"]), f"band_{u}": self.bands[name][0],
                            "band_from": self.bands[name][1], "unit": u, "drift": drift,
                            "since_t": _number(v["since_t"]) if drift else None,
                            "cause": (CAUSES[cause] or None) if drift and 0 <= cause < len(CAUSES) else None,
                            "size": _number(v["size"]) if drift and cause else None}
        return {"running": self._proc.health().get("running", False), "band_deg": self.band_deg, "joints": joints}

    def health(self) -> dict:
        return self._proc.health()

    def join(self, timeout: float = 2.0) -> None:
        self._proc.join(timeout)


def _number(x: float) -> float | None:
    return x if x == x else None


# -- in the model process ------------------------------------------------------------------------
def serve(child: Child, rings_dir: str, rig: RigConfig, joints: list[str], shared: SharedMemory) -> None:
    """Take the state messages, run the models, send the ``model`` topic and events back, until
    the feed ends (the loop's END) or the daemon is gone."""
    import msgpack
    import zmq

    from controllers.drift_watch import ModelWatch

    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    watch = ModelWatch(rig)
    ctx = zmq.Context()
    feed = ctx.socket(zmq.PULL)
    feed.setsockopt(zmq.RCVHWM, MODEL_FEED_HWM)
    out = ctx.socket(zmq.PUSH)
    out.setsockopt(zmq.SNDHWM, 1000)
    for sock in (feed, out):
        sock.setsockopt(zmq.LINGER, 0)
    feed.connect(endpoint(rings_dir, MODEL_FEED))
    out.connect(endpoint(rings_dir, MODEL_OUT))
    child.ready()
    period = 1.0 / rig.model_watch.publish_hz
    next_t = -math.inf
    seq = 0
    since: dict[str, float] = {}
    residuals: dict[str, list] = {name: [] for name in watch.joints}
    first_cycle = None
    while child.parent_alive():
        if not feed.poll(500):
            continue
        frames = feed.recv_multipart()
        if frames[0] == b"":
            break  # the loop's END
        columns = msgpack.unpackb(frames[1], raw=False)
        if first_cycle is None and columns["cycle"]:
            first_cycle = columns["cycle"][0]
        for name, r in watch.feed(columns).items():
            residuals[name] += r
        if not math.isfinite(watch.t) or watch.t < next_t:
            continue
        next_t = watch.t + period
        message, verdicts = watch.judge()
        seq += 1
        for name, stats in message["joints"].items():
            stats[f"residual_{stats['unit']}"] = [x if x == x else None for x in residuals[name]]
            residuals[name] = []
        message.update(seq=seq, first_cycle=first_cycle)
        first_cycle = None
        for v in verdicts:
            if v.action == "drift":
                since[v.joint] = watch.t
        # the status first: a client told of a drift by its event finds it in the status too
        write_locked(shared.seq, shared.values, _status_row(watch, message, joints, since))
        _send(out, MODEL_TOPIC, msgpack.packb(message))
        for v in verdicts:
            event = {"kind": "model", "action": v.action, "joint": v.joint, "cause": v.cause, "t_model": watch.t}
            if v.details:
                event.update(likely=v.details.get("likely"), best=v.details.get("best"), size=v.details.get("size"),
                             explained=v.details.get("explained"), onset_t=v.details.get("onset_t"))
            _send(out, EVENT, msgpack.packb(event))
    feed.close()
    out.close()
    ctx.term()


def _status_row(watch, message: dict, joints: list[str], since: dict[str, float]) -> list[float]:
    """The status numbers (``NUMBERS``) of each joint, in ``joints``' order."""
    row = []
    for name in joints:
        stats, w = message["joints"][name], watch.joints[name]
        cause = (w.cause or {}).get("likely") if w.flagged else None
        row += [float(stats["anchored"]), stats[f"rms_{w.unit}"], stats[f"mean_{w.unit}"], float(w.flagged),
                since.get(name, math.nan), float(CAUSES.index(cause)) if cause else 0.0,
                (w.cause or {}).get("size", math.nan) if cause else math.nan]
    return row


def _send(sock, topic: bytes, body: bytes) -> None:
    import zmq
    try:
        sock.send_multipart((topic, body), zmq.NOBLOCK)
    except zmq.Again:
        pass  # no messenger to take it now (one restarting): this message is lost, the next one comes
