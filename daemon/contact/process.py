"""The array pressure sensor beside the loop (rig-facts §3; the rig file's
``[contact_sensor]``): its frames arrive at up to 4 kHz, faster than the loop, so a process
of their own reads them and runs the contact estimator (controllers.contact_force) on each;
the loop takes the latest estimate from shared memory with its frame's time and age, and
never waits on it (a seqlock, as the off-loop transports share their samples).

The worker keeps the sensor's pace by the clock: frame k is due at start + k / rate_hz;
when the estimator falls behind it takes the newest frame due and counts the ones it passed
over (``late_frames``), so the estimate is never older than it has to be. A frame that cannot
be a reading is counted (``bad_frames``) and its reason kept, never estimated on.

Frames come from the source the rig file names (``contact_sensor.source``, loaded by name in
this process: hal.taxel_array's FrameSource); the process is a helper (hal.process.Helper)
that dies with the daemon and says it is ready with its first estimate.

If it dies, the loop's port starts another at its next look (once a second: a ``contact``
event), which goes on with the sensor's frame count (frames are numbered from the sensor's
first start) and a fresh estimator. An estimate is *valid* while its process runs and it is
no older than ``controllers.contact_force.STALE_MEMORIES`` of the estimator's memories (the
gap after which the estimator itself starts its track again: 32 ms by default); otherwise
the ``contact`` topic says why (``sensor``: ``stale`` or ``restarting``) and carries NaN for
every number of the estimate, never the last one as if it were current, and never ``null``,
which means that nothing touches the pad.
"""
from __future__ import annotations

import ctypes
import math
import time
import weakref

from controllers.contact_force import STALE_MEMORIES
from hal.errors import TransportTimeout
from hal.process import Child, Helper, HelperFailed, SharedMemory
from hal.seqlock import try_read, write_locked
from hal.taxel_array import ContactSensorConfig

from daemon.wire.telemetry_rows import CONTACT_FIELDS as FIELDS

INTEGER_FIELDS = ("taxels", "track_frames")
COUNTERS = ("frames", "late_frames", "bad_frames", "contact_frames")
HEAD = 3  # frame index, its time.monotonic(), whether an estimate follows; then FIELDS
_ERROR_BYTES = 240
LOOP_READ_TRIES = 200  # the loop's side: a few microseconds, then the last whole estimate


def _shared() -> SharedMemory:
    return SharedMemory({"seq": ctypes.c_uint64, "values": ctypes.c_double * (HEAD + len(FIELDS)),
                         "counters": ctypes.c_uint64 * len(COUNTERS), "stop": ctypes.c_bool,
                         "error": ctypes.c_char * _ERROR_BYTES, "t0": ctypes.c_double})
UNKNOWN = {name: (0 if name in INTEGER_FIELDS else math.nan) for name in FIELDS}  # an estimate not valid now


class ContactSensor:
    """The loop's side: :meth:`open` starts the worker, :meth:`latest` is the newest estimate."""

    def __init__(self, config: ContactSensorConfig, clock):
        self.config = config
        self.clock = clock  # the loop's clock (seconds)
        self._shared: SharedMemory | None = None
        self._process: Helper | None = None
        self._latest: dict | None = None  # the newest estimate, as the topic carries it (its age aside)
        self._latest_mono = 0.0  # its frame's time.monotonic()
        self._last_seq = 0
        self.stale_s = STALE_MEMORIES * config.memory_ms / 1e3  # an estimate older than this is not valid [s]
        self.restarting = False  # its process died and the next has not given an estimate yet

    def open(self) -> None:
        """Start the worker and wait for its first estimate (the frames are made up front),
        up to the rig file's ``contact_sensor.open_timeout_s``."""
        self._shared = shared = _shared()
        self._process = Helper("daemon.contact.process:serve", (shared, self.config), name="the contact sensor",
                               pass_fds=(shared.fd,))
        self._finalizer = weakref.finalize(self, _stop, shared, self._process)
        try:
            self._process.start(self.config.open_timeout_s)
        except HelperFailed as exc:
            reason = self.last_error() or str(exc)
            self.close()
            raise TransportTimeout(f"contact_sensor: no frame within {self.config.open_timeout_s:g} s of opening: {reason}") from None

    def close(self) -> None:
        if self._process is not None:
            self._finalizer.detach()
            _stop(self._shared, self._process)
            self._process = None

    def latest(self) -> dict | None:
        """The newest estimate as the ``contact`` topic carries it (its frame's time on the
        loop's clock, its age, whether it is valid and why not); None before the first.
        Constant cost: a copy of 20 numbers."""
        shared = self._shared
        if shared is None:
            return None
        found = try_read(shared.seq, shared.values, tries=LOOP_READ_TRIES)
        if found is not None and found[0] != self._last_seq:
            self._last_seq = found[0]
            self.restarting = False
            frame, self._latest_mono, touching = found[1][:HEAD]
            self._latest = {"frame": int(frame), "frame_t": self.clock() - self._age(),
                            "contact": ({name: (int(v) if name in INTEGER_FIELDS else v)
                                         for name, v in zip(FIELDS, found[1][HEAD:])} if touching else None)}
        if self._latest is None:
            return None
        age = self._age()
        sensor = "restarting" if self.restarting else "running" if age <= self.stale_s else "stale"
        latest = self._latest if sensor == "running" else {**self._latest, "contact": UNKNOWN}
        return {**latest, "age_s": age, "valid": sensor == "running", "sensor": sensor, **self.counters()}

    def check(self) -> str | None:
        """The loop's look (once a second, never waiting): a dead process is started again,
        its estimate not valid until the new one's first; what happened, as an event's cause."""
        process = self._process
        if process is None:
            return None
        code = process.restart_if_dead()
        if code is None:
            try:
                process.poll_ready()  # (health: running once the new one is)
            except HelperFailed:
                pass  # it exits: the next look starts another
            return None
        shared = self._shared
        if shared.seq.value & 1:  # it died writing: the half-written estimate is never read
            shared.seq.value += 1
            self._last_seq = shared.seq.value
        self.restarting = True
        reason = self.last_error()
        return (f"the contact sensor's process exited (code {code}) and was restarted (restart {process.restarts}); "
                f"the contact estimate is not valid until its first frame{f' (its last error: {reason})' if reason else ''}")

    def health(self) -> dict:
        return self._process.health() if self._process is not None else {}

    def _age(self) -> float:
        return max(time.monotonic() - self._latest_mono, 0.0)

    def counters(self) -> dict:
        return dict(zip(COUNTERS, self._shared.counters[:])) if self._shared is not None else {}

    def last_error(self) -> str:
        return self._shared.error.value.decode(errors="replace") if self._shared is not None else ""


def _stop(shared: SharedMemory, process: Helper) -> None:
    shared.stop.value = True
    process.join(2.0)


# -- in the worker process --------------------------------------------------------------------
def serve(child: Child, shared: SharedMemory, config: ContactSensorConfig) -> None:
    """Frames at the sensor's rate through the device and the estimator, until told to stop
    or the daemon is gone."""
    from controllers.contact_force import ContactEstimator  # the estimator lives in this process alone
    from hal.taxel_array import TaxelArray, load_frame_source

    source = load_frame_source(config.source).from_config(config)
    device = TaxelArray(config.calibration())
    estimator = ContactEstimator(config.memory_ms / 1e3, config.beta_memory_ms / 1e3, frame_hz=config.rate_hz)
    counters = shared.counters
    period = 1.0 / config.rate_hz
    start = shared.t0.value or time.monotonic()  # a restarted process goes on with the sensor's frame count
    shared.t0.value = start
    last = int((time.monotonic() - start) / period) - 1  # (a restart's gap is not the estimator falling behind)
    while not shared.stop.value and child.parent_alive():
        due = int((time.monotonic() - start) / period)
        if due <= last:
            time.sleep(max(start + (last + 1) * period - time.monotonic(), 0.0))
            continue
        counters[1] += max(due - last - 1, 0)  # passed over: the estimator fell behind
        elapsed, last = due - last, due
        try:
            found = estimator.update(device.pressures(source.frame(due)), frames=elapsed)
        except ValueError as exc:
            counters[2] += 1
            shared.error.value = str(exc).encode()[:_ERROR_BYTES - 1]
            continue
        counters[0] += 1
        counters[3] += found is not None
        row = [float(due), start + due * period, float(found is not None)]
        row += [float(getattr(found, name)) for name in FIELDS] if found is not None else [math.nan] * len(FIELDS)
        write_locked(shared.seq, shared.values, row)
        child.ready()  # (once: the first estimate is there)
