"""The serial bridge's firmware (firmware/serial-bridge), built here for this machine and
driven by a real daemon over a pseudo-terminal, its board's converters bound to the simulated
rig's plant (sim_backend.firmware_plant): tracking a move as the in-process rig does, bytes
injected on the line (resynchronisation inside rejected bytes, a corrupted outputs frame
never applied), corrupted replies in the daemon's counters, the dead-man when the daemon is
killed, a query; and the C core's own unit tests.

The build goes into a directory of pytest's (``make host BUILD=...``): nothing is written into
the checkout. Without gcc or make the tests are skipped, saying so (.ci/run installs both)."""
from __future__ import annotations

import json
import math
import os
import re
import shutil
import signal
import subprocess
import threading
import time
from pathlib import Path

import pytest

from daemon.client.client import Client
from hal import config
from hal import serial_frames as F
from hal.transport import volts_to_counts
from sim_backend import firmware_plant
from tests.daemons import real_daemon, wait_for_own_daemon
from tests.wirehelpers import MOVE_DEG, MOVE_S, move_and_track, start_peer, stop_peer, wire_loop

ROOT = Path(__file__).resolve().parents[1]
FIRMWARE = ROOT / "firmware" / "serial-bridge"
DEADMAN_US = 20_000  # docs/serial-bridge.md: 20 ms without outputs, the safe outputs
WAIT_S = 60.0  # every event is waited for; the bound only ends a hang

pytestmark = pytest.mark.skipif(not (shutil.which("gcc") and shutil.which("make")),
                                reason="the firmware's host build needs gcc and make (.ci/run installs them)")


@pytest.fixture(scope="module")
def build(tmp_path_factory) -> Path:
    """``make host`` into a directory of the test session's: warning-free (-Werror) or failed."""
    out = tmp_path_factory.mktemp("firmware-build")
    done = subprocess.run(["make", "-C", str(FIRMWARE), "host", f"BUILD={out}"], capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "warning" not in (done.stdout + done.stderr).lower()
    return out


class Bridge:
    """The firmware's host build on a link under the test's directory, its plant served from a
    thread of this process."""

    def __init__(self, build: Path, link: Path, *options: str):
        self.link = link
        self.proc, self.plant = firmware_plant.start(str(build / "bridge-host"), config.load(), str(link), *options)
        self._done = threading.Event()
        self._server = threading.Thread(target=self.plant.serve, args=(self._done.is_set,), daemon=True)
        self._server.start()
        try:
            wait_until(lambda: link.exists() or self.proc.poll() is not None, "the firmware to come up")
            assert self.proc.poll() is None, f"the firmware exited with {self.proc.returncode}: {self.plant.refused}"
        except BaseException:
            self.proc.kill()
            self.stop(check=False)
            raise

    def stop(self, check: bool = True) -> dict:
        """Stop the firmware: its counters (its last line)."""
        if self.proc.poll() is None:
            self.proc.terminate()
        out, _ = self.proc.communicate(timeout=WAIT_S)
        self._done.set()
        self._server.join(WAIT_S)
        self.plant.sock.close()
        if not check:
            return {}
        assert self.proc.returncode == 0, out
        return json.loads(out.strip().splitlines()[-1])


@pytest.fixture
def bridges(build, tmp_path):
    """Start bridges with ``bridges(*options)``; each is stopped at the end."""
    started = []

    def start(*options: str) -> Bridge:
        started.append(Bridge(build, tmp_path / f"bridge{len(started)}", *options))
        return started[-1]
    yield start
    for bridge in started:
        if bridge.proc.poll() is None:
            bridge.stop(check=False)


class DeviceBridge:
    """The firmware and its plant in a process of their own (``python -m sim_backend.firmware_plant``)
    at a device's niceness, as the other wire tests' peers (tests/wirehelpers.py): a bridge has a
    processor of its own. :class:`Bridge` serves its plant from a thread of the test's process,
    which a loaded machine held off the sample path for 0.28 s (beside two CPU hogs)."""

    def __init__(self, build: Path, link: Path):
        self.link = link
        self.proc = start_peer("sim_backend.firmware_plant", "--firmware", str(build / "bridge-host"),
                               "--link", str(link), ready=link.exists)

    def stop(self) -> dict:
        """Stop it: the firmware's counters (its last line)."""
        self.proc.terminate()
        out, _ = self.proc.communicate(timeout=WAIT_S)
        assert self.proc.returncode == 0, out
        return json.loads(out.decode().strip().splitlines()[-1])


@pytest.fixture
def device_bridge(build, tmp_path):
    bridge = DeviceBridge(build, tmp_path / "device-bridge")
    yield bridge
    if bridge.proc.poll() is None:
        stop_peer(bridge.proc, hard=True)


def wait_until(condition, what: str, every_s: float = 0.002) -> None:
    deadline = time.monotonic() + WAIT_S
    while not condition():
        assert time.monotonic() < deadline, f"waited {WAIT_S} s for {what}"
        time.sleep(every_s)


class Daemon:
    """A real daemon (private endpoints, stall-tolerant rig) on the bridge's link, the arm
    enabled. Stale input trips at 1 s, as in the other wire tests (tests/wirehelpers.py,
    RELAXED): what is tested is the firmware, not how promptly a busy machine schedules the
    three processes a sample passes through."""

    def __init__(self, directory: Path, link: Path):
        self.proc, eps = real_daemon(directory, "--transport", "serial", "--transport-option", f"port={link}",
                                     "--transport-option", "open_timeout_s=30", "--safety", "stale_after_s=1.0")
        self.client = Client(**eps, timeout=10.0)
        try:
            wait_for_own_daemon(self.client, self.proc)
            self.client.acquire_lease()
            self.client.keep_lease()
            self.client.enable()
        except BaseException:
            self.close(kill=True)
            raise

    def close(self, kill: bool = False) -> None:
        if self.client is not None:
            self.client.close()
            self.client = None
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGKILL if kill else signal.SIGTERM)
        self.proc.wait(WAIT_S)


@pytest.fixture
def daemons(tmp_path):
    started = []

    def start(link: Path) -> Daemon:
        directory = tmp_path / f"daemon{len(started)}"
        directory.mkdir()
        started.append(Daemon(directory, link))
        return started[-1]
    yield start
    for daemon in started:
        daemon.close()


def test_the_core_passes_its_unit_tests(build):
    """Frames, CRC check value 0x29B1, resynchronisation, and the bridge's rules on a fake
    board and clock (firmware/serial-bridge/test/test_core.c)."""
    done = subprocess.run([str(build / "test-core")], capture_output=True, text=True, timeout=WAIT_S)
    assert done.returncode == 0, done.stdout
    passed, failed = map(int, re.search(r"^(\d+) passed, (\d+) failed$", done.stdout, re.M).groups())
    assert failed == 0 and passed >= 30, done.stdout


def test_a_layout_that_is_not_the_rig_files_is_refused(bridges):
    """The board table's three-joint entry against the two-joint rig: the plant refuses it and
    the firmware exits, naming the counts, before any daemon could talk to it."""
    with pytest.raises(AssertionError, match="exited with 2"):
        bridges("--layout", "cylinder-3")


def test_a_query_is_answered_and_changes_no_output_nor_feeds_the_dead_man(bridges):
    """This test plays the host: a query (no payload) is answered with the rig's inputs under
    its seq and moves nothing; outputs move the rig; queries alone then let the dead-man
    write the safe outputs 20 ms after the last outputs."""
    bridge = bridges()
    rig = bridge.plant.rig
    fd = os.open(bridge.link, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    reader = F.FrameReader()
    try:
        def ask(seq: int, counts=()) -> F.Frame:
            os.write(fd, F.encode(F.OUTPUTS, seq, counts))
            got = []

            def answered():
                try:
                    got.extend(reader.feed(os.read(fd, 4096)))
                except BlockingIOError:
                    pass
                return got
            wait_until(answered, f"the answer to seq {seq}")
            return got[0]

        reply = ask(0xBEEF)
        assert reply.kind == F.INPUTS and reply.seq == 0xBEEF and len(reply.counts) == rig.n_in
        supply = reply.counts[2]  # ai6, the potentiometers' 5 V supply: half the 0..10 V span
        assert abs(supply - 32768) < 100, reply.counts
        assert [u.counts for u in bridge.plant.updates] == [bridge.plant.safe_counts]  # its start, nothing since
        driven = (40000, 30000, 40000, 30000)
        assert ask(1, driven).seq == 1 and bridge.plant.updates[-1].counts == driven
        assert rig.sim.output_volts == pytest.approx([c * 10 / 65535 for c in driven], abs=1e-6)
        seq = 2
        while bridge.plant.updates[-1].counts == driven:  # queries only, as fast as they are answered
            assert ask(seq).seq == seq
            seq += 1
        last, safe = bridge.plant.updates[-2], bridge.plant.updates[-1]
        assert safe.counts == bridge.plant.safe_counts and seq > 3
        assert (safe.t_us - last.t_us) % 2**32 > DEADMAN_US
    finally:
        os.close(fd)
    counters = bridge.stop()
    assert counters["queries"] == seq - 1 and counters["deadman"] == 1 and counters["crc_errors"] == 0


@pytest.mark.slow(seconds=12)
def test_a_daemon_tracks_a_move_through_the_firmware_as_in_process(device_bridge, daemons):
    """The move the serial peer's test makes (tests/wirehelpers.py), through the real daemon
    and the real firmware: the largest joint errors agree with the same move in process on the
    virtual clock within 0.5 deg and what late samples explain (a sample ``g`` old leaves the
    controller up to ``g`` behind a reference at the move's top speed, 1.5 offset / duration)."""
    bridge = device_bridge
    daemon = daemons(bridge.link)
    client = daemon.client
    subscription = client.subscribe((b"state",))
    try:
        time.sleep(0.2)  # holding, as the in-process move holds 200 cycles
        start = [j["setpoint"] for j in client.status()["joints"].values()]  # [deg]
        moved = client.set(angles_deg=[a + d for a, d in zip(start, MOVE_DEG)], duration_s=MOVE_S)
        end_cycle = moved["cycle"] + int((MOVE_S + 1.0) * 1000)
        worst, times, cycle = [0.0, 0.0], [], 0
        while cycle < end_cycle:
            got = subscription.receive(timeout=WAIT_S)
            assert got is not None, "no state message"
            rows = got[1]
            for cycle, t, *errors in zip(rows["cycle"], rows["t"], rows["bottom.error"], rows["middle.error"]):
                if moved["cycle"] <= cycle < end_cycle:
                    worst = [max(w, abs(math.degrees(e))) for w, e in zip(worst, errors)]
                    times.append(t)
        status = client.status()
    finally:
        subscription.close()
    assert status["state"] == "enabled" and status["trips"] == 0, status["cause"]
    counters = status["transport"]["counters"]
    assert counters["crc_errors"] == counters["wrong_replies"] == 0, counters
    in_process = move_and_track(wire_loop(None, virtual=True)[0])
    late = max(b - a for a, b in zip(times, times[1:]))  # the longest a sample stood for the next
    allowed = [0.5 + 1.5 * d / MOVE_S * late for d in MOVE_DEG]
    assert all(abs(w - p) < a for w, p, a in zip(worst, in_process, allowed)), (worst, in_process, late)
    daemon.close()
    firmware = bridge.stop()
    assert firmware["replies"] > 3000 and firmware["crc_errors"] == firmware["refused"] == 0, firmware
    # a reply to a request older than one already taken is counted and never taken; a firmware
    # that echoed the sequence number wrongly would have all of its replies here, not some
    assert counters["unexpected_seq"] < 0.5 * firmware["replies"], (counters, firmware)


def noise_bundle(i: int) -> bytes:
    """What the test writes into the line between the daemon's frames (one write: a pty
    never splits it): a header claiming 64 bytes whose 72 bytes hide a query (seq 0xF000 + i)
    that only a resynchronisation inside rejected bytes finds; an impossible header; an
    outputs frame at full scale with a flipped bit, which must never reach the regulators."""
    query = F.encode(F.OUTPUTS, 0xF000 + i, [])
    swallowing = F.SYNC + bytes([F.OUTPUTS, 0, 0, F.MAX_PAYLOAD]) + query
    swallowing += bytes(F.OVERHEAD + F.MAX_PAYLOAD - len(swallowing))  # zeros, its "crc" too
    assert F.crc16(swallowing[2:-2]) != 0  # so it fails its CRC
    impossible = F.SYNC + bytes([0x07, 0, 0, 2])
    corrupted = bytearray(F.encode(F.OUTPUTS, 0xE000 + i, [65535] * 4))
    corrupted[8] ^= 0x01
    bundle = swallowing + impossible + bytes(corrupted)
    assert bundle.count(F.SYNC) == 4  # no stray sync pattern to count differently
    return bundle


@pytest.mark.slow(seconds=7)
def test_bytes_injected_on_the_line_are_rejected_and_the_frames_inside_them_found(bridges, daemons):
    """The test writes noise bundles into the line beside the daemon: the firmware rejects
    each part, counting it, applies none, and answers the query hidden in each, which the
    daemon counts as a reply to no request of its own; its own exchanges go on untouched."""
    bridge = bridges()
    daemon = daemons(bridge.link)
    before = daemon.client.status()["transport"]["counters"]["unexpected_seq"]
    n = 20
    fd = os.open(bridge.link, os.O_WRONLY | os.O_NOCTTY)
    try:
        for i in range(n):
            os.write(fd, noise_bundle(i))
            time.sleep(0.01)
    finally:
        os.close(fd)
    wait_until(lambda: daemon.client.status()["transport"]["counters"]["unexpected_seq"] >= before + n,
               "the answers to the hidden queries", every_s=0.05)
    status = daemon.client.status()
    counters = status["transport"]["counters"]
    assert status["state"] == "enabled" and status["trips"] == 0, status["cause"]
    assert counters["crc_errors"] == counters["bad_headers"] == counters["wrong_replies"] == 0, counters
    daemon.close()
    firmware = bridge.stop()
    assert firmware["crc_errors"] == 2 * n and firmware["bad_headers"] == n, firmware
    assert firmware["queries"] >= n and firmware["refused"] == 0, firmware
    assert all(u.counts != (65535,) * 4 for u in bridge.plant.updates)


@pytest.mark.slow(seconds=7)
def test_corrupted_replies_are_counted_by_the_daemon_which_carries_on(bridges, daemons):
    """The firmware flips a bit in every 20th reply (as the serial peer's --corrupt-every):
    the daemon drops each on its CRC, counts it, and holds the arm on the good ones."""
    bridge = bridges("--corrupt-every", "20")
    daemon = daemons(bridge.link)
    wait_until(lambda: daemon.client.status()["transport"]["counters"]["crc_errors"] >= 25, "corrupted replies",
               every_s=0.05)
    status = daemon.client.status()
    counters = status["transport"]["counters"]
    assert status["state"] == "enabled" and status["trips"] == 0, status["cause"]
    assert counters["wrong_replies"] == 0 and counters["discarded_bytes"] >= 14 * counters["crc_errors"], counters
    daemon.close()
    firmware = bridge.stop()
    assert 25 <= counters["crc_errors"] <= firmware["corrupted"] == firmware["replies"] // 20, (counters, firmware)


@pytest.mark.slow(seconds=5)
def test_the_firmware_writes_the_safe_outputs_20_ms_after_the_daemon_is_killed(bridges, daemons):
    """SIGKILL: the daemon writes nothing more. The firmware's dead-man writes the rig file's
    safe outputs once, at its first look past 20 ms after the last outputs (by its own clock:
    the look before was not past it), so within 20 ms and one frame on a machine that lets it
    look that often; and nothing after."""
    bridge = bridges()
    daemon = daemons(bridge.link)
    plant = bridge.plant
    assert plant.safe_counts == tuple(volts_to_counts(plant.rig.safe_volts, plant.rig.sim.outputs))
    wait_until(lambda: len(plant.updates) > 100 and plant.updates[-1].counts != plant.safe_counts, "outputs",
               every_s=0.05)
    daemon.close(kill=True)
    wait_until(lambda: plant.updates[-1].counts == plant.safe_counts, "the safe outputs")
    time.sleep(0.1)
    updates = list(plant.updates)
    last, safe = updates[-2], updates[-1]
    assert last.counts != safe.counts == plant.safe_counts  # nothing after the safe outputs
    delay_us = (safe.t_us - last.t_us) % 2**32
    looked_us = (safe.t_us - safe.gap_us - last.t_us) % 2**32
    assert looked_us <= DEADMAN_US < delay_us, (looked_us, delay_us, safe.gap_us)
    assert plant.rig.sim.output_volts == pytest.approx(plant.rig.safe_volts, abs=1e-3)
    assert bridge.stop()["deadman"] >= 1  # and any a stall of the daemon's caused before
