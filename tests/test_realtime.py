"""The real-time set-up's PM QoS request: written as the kernel expects, held while the
process runs, and a clear warning (never a failure) where it is not permitted."""
import os
import struct

import pytest

from daemon.service import realtime


def _release_held():
    while realtime._held:
        realtime._held.pop().close()


def _current(path: str) -> int:
    with open(path, "rb") as f:
        return struct.unpack("i", f.read(4))[0]


def test_the_request_is_a_native_int32_and_stays_open(tmp_path):
    path = tmp_path / "cpu_dma_latency"
    path.write_bytes(b"")
    try:
        assert realtime.hold_idle_latency(7, str(path)) is None
        assert path.read_bytes() == struct.pack("i", 7)
        assert len(realtime._held) == 1 and not realtime._held[0].closed
    finally:
        _release_held()


def test_a_refused_request_is_a_warning_naming_the_file(tmp_path):
    warning = realtime.hold_idle_latency(0, str(tmp_path / "missing" / "cpu_dma_latency"))
    assert "cpu_dma_latency 0 us not applied" in warning and "write access" in warning
    assert realtime._held == []


@pytest.mark.skipif(not os.access(realtime.CPU_DMA_LATENCY, os.W_OK), reason="needs write access to the PM QoS file")
def test_the_kernel_holds_the_request_until_it_is_released():
    before = _current(realtime.CPU_DMA_LATENCY)
    try:
        assert realtime.hold_idle_latency(0) is None
        assert _current(realtime.CPU_DMA_LATENCY) == 0
    finally:
        _release_held()
    assert _current(realtime.CPU_DMA_LATENCY) == before
