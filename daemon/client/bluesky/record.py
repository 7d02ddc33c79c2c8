"""A daemon-side recording as a Bluesky "flyer": one reference (a move, a path, an excitation)
run with ``record`` on, the daemon's 1 kHz record of it turned into HDF5 and added to the run
as an external resource (StreamResource / StreamDatum): the run's data is every cycle, not a
scan's handful of points.

``prepare(Flight(...))`` says which reference; ``kickoff`` starts it (the daemon records from
half a second before to 3 s after); ``complete`` waits for the reference's end (and for the
joints named to settle), then for the daemon's file, and writes ``<directory>/<name>.h5``;
``collect`` then emits its documents. The daemon's record directory must be readable where
the plan runs: the daemon's PC, or a shared mount (docs/bluesky.md).
"""
from __future__ import annotations

import asyncio
import os
import time
from collections.abc import Callable
from dataclasses import dataclass

import h5py
import numpy as np
from bluesky.protocols import Collectable, Flyable, Preparable, WritesStreamAssets
from event_model import compose_stream_resource
from ophyd_async.core import AsyncStatus

from daemon.client import progress
from daemon.client.client import Client
from daemon.client.bluesky.device import TRIP_GRACE_S, PneumadRig, stopped_within
from daemon.recordings import reading


@dataclass
class Flight:
    """A reference to run and record: ``send(client)`` starts it with ``record=True`` (when
    the flight starts, so it may read where the arm is then) and returns the daemon's reply;
    ``settle(reply)``: the joints' targets [deg] to wait to settle at after it (none: until
    the reference has ended)."""

    send: Callable[[Client], dict]
    settle: Callable[[dict], dict[str, float]] | None = None


class DaemonRecord(Flyable, Preparable, Collectable, WritesStreamAssets):
    """The recordings of one rig's references, into ``directory`` as HDF5."""

    def __init__(self, rig: PneumadRig, directory: str, name: str = ""):
        self.rig, self.directory = rig, os.path.abspath(directory)
        self._name = name or f"{rig.name}_record"
        self._flight: Flight | None = None
        self._recording: str | None = None
        self._file: str | None = None
        self._rows = 0
        self._emitted = False
        self._stopped = asyncio.Event()  # the RunEngine paused the flight (a suspension: it is flown again)

    def pause(self) -> None:
        """The RunEngine suspends the plan (the arm tripped: daemon.client.bluesky.suspend): the
        flight in progress ends without failing; the plan flies it again from its checkpoint."""
        self._stopped.set()

    @property
    def name(self) -> str:
        return self._name

    @property
    def parent(self):
        return None

    def _keys(self) -> list[tuple[str, str, str]]:
        """(data key, HDF5 dataset, SI unit) of each number of the cycle record, from the rig's
        layout (``mode``, a name, is in the file but not a stream's number)."""
        return [(f"{self.name}_{f.name.replace('.', '_')}", dataset(f.name), f.unit)
                for f in self.rig.link.layout.fields if f.name != "mode"]

    @AsyncStatus.wrap
    async def prepare(self, value: Flight) -> None:
        self._flight, self._recording, self._file, self._rows, self._emitted = value, None, None, 0, False

    @AsyncStatus.wrap
    async def kickoff(self) -> None:
        self._stopped.clear()
        if self._flight is None:
            raise RuntimeError(f"{self.name}: prepare() a Flight before kickoff")
        reply = await asyncio.to_thread(self._flight.send, self.rig.link.client)
        self._settle_deg = self._flight.settle(reply) if self._flight.settle is not None else {}
        if not reply.get("recording"):
            raise RuntimeError(f"{self.name}: the daemon did not record the reference (no recording in {reply})")
        self._recording = reply["recording"]  # the name the daemon records it under
        self._total_s = float(reply.get("total_s") or reply.get("duration_s") or 0.0)
        self.rig.link.forget_status()

    @AsyncStatus.wrap
    async def complete(self) -> None:
        link = self.rig.link
        if self._settle_deg:
            await self.rig.settled(self._settle_deg, self._total_s, self._stopped)
            if self._stopped.is_set():
                return
        else:
            ended = await asyncio.to_thread(_follow, link.client, self._total_s)
            if ended["state"] != "enabled":
                if await stopped_within(self._stopped, TRIP_GRACE_S):
                    return
                raise RuntimeError(f"{link.rig_name}: the arm is {ended['state']}: {ended['cause']}")
        path = await asyncio.to_thread(progress.recording_file, link.client, self._recording)
        if path is None or not os.path.exists(path):
            raise RuntimeError(f"{link.rig_name}: the daemon's recording {self._recording} is not readable here "
                               f"({path}): run the plan on the daemon's PC or mount its record directory")
        self._file = os.path.join(self.directory, f"{self._recording}.h5")
        self._rows = await asyncio.to_thread(to_hdf5, path, self._file)

    def describe_collect(self) -> dict:
        return {key: {"source": f"{self.rig.link.source('record', dataset.strip('/'))}", "shape": [],
                      "dtype": "integer" if dataset == "/cycle" else "number", "units": unit,
                      "dtype_numpy": "<i8" if dataset == "/cycle" else "<f8", "external": "STREAM:"}
                for key, dataset, unit in self._keys()}

    def get_index(self) -> int:
        return self._rows

    def collect_asset_docs(self, index: int | None = None):
        if self._file is None or self._emitted or not self._rows:
            return
        stop = self._rows if index is None else min(index, self._rows)
        self._emitted = True
        for key, dataset, _ in self._keys():
            bundle = compose_stream_resource(mimetype="application/x-hdf5", uri=f"file://localhost{self._file}",
                                             data_key=key, parameters={"dataset": dataset, "chunk_shape": (stop,)})
            yield "stream_resource", bundle.stream_resource_doc
            yield "stream_datum", bundle.compose_stream_datum({"start": 0, "stop": stop})


def _follow(client, total_s: float) -> dict:
    """Until the reference has ended (or the arm left the enabled state), quietly."""
    deadline = time.monotonic() + total_s + 60.0
    while True:
        status = client.status()
        if status["state"] != "enabled" or status["reference_remaining_s"] <= 0.0 or time.monotonic() > deadline:
            return {"state": status["state"], "cause": status.get("cause", "")}
        time.sleep(0.1)


def dataset(name: str) -> str:
    """The HDF5 dataset of a column :func:`daemon.recordings.reading.load` names: its dots as
    groups (``bottom.u.v_mv`` -> ``/bottom/u/v_mv``)."""
    return "/" + name.replace(".", "/")


def to_hdf5(recording: str, out: str) -> int:
    """The state stream of a daemon's recording as HDF5 datasets, one per field of its cycle
    record (``/t``, ``/cycle``, ``/<joint>/position``, ``/<joint>/u/v_mv`` ..., SI units, as
    :func:`daemon.recordings.reading.load` names them; ``/mode`` as text), the internals and
    contact streams under ``/internals`` and ``/contact``; the number of rows."""
    columns = reading.load(recording)
    os.makedirs(os.path.dirname(out) or ".", exist_ok=True)
    with h5py.File(out, "w") as f:
        for name, values in columns.items():
            values = np.asarray(values)
            if values.dtype.kind in "OU":  # text (the mode's name): HDF5 takes it as bytes
                values = values.astype("S")
            f.create_dataset(dataset(name), data=values)
            if name in columns.layout:
                f[dataset(name)].attrs["unit"] = columns.layout[name].unit
        f.attrs["source"] = os.path.abspath(recording)
    return len(columns["t"])
