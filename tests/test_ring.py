"""The shared-memory ring between the loop and the messenger: order, wrap-around, a full
ring refusing without harm, and two processes at once."""
import multiprocessing

import pytest

from daemon.wire.ring import Ring, RingError


def test_messages_come_out_in_order_with_their_tags(tmp_path):
    ring = Ring(str(tmp_path / "r"), 4096)
    assert ring.get() is None
    for i in range(5):
        assert ring.put(i, bytes([i]) * i)
    assert [ring.get() for _ in range(6)] == [(i, bytes([i]) * i) for i in range(5)] + [None]


def test_entries_split_across_the_end_of_the_circle_come_back_whole(tmp_path):
    ring = Ring(str(tmp_path / "r"), 100)
    for round_ in range(50):  # 37-byte entries walk the circle's end through every offset
        payload = bytes((round_ + k) % 256 for k in range(25))
        assert ring.put(round_, payload)
        assert ring.get() == (round_, payload)


def test_a_view_of_a_reused_buffer_is_copied_in_whole_pieces_or_split(tmp_path):
    """The loop puts views of buffers it then reuses: what comes out is what was put, whether
    the entry fits before the circle's end or is split across it."""
    ring = Ring(str(tmp_path / "r"), 100)
    buffer = bytearray(40)
    for round_ in range(30):  # 42- and 36-byte entries: some in one piece, some split at the end
        size = 30 if round_ % 2 else 24
        buffer[:size] = bytes((round_ * 7 + k) % 256 for k in range(size))
        expected = bytes(buffer[:size])
        assert ring.put(round_, memoryview(buffer)[:size])
        buffer[:] = bytes(40)  # reused at once
        assert ring.get() == (round_, expected)
    assert ring.put(99, bytearray(b"whole")) and ring.get() == (99, b"whole")
    exact = Ring(str(tmp_path / "exact"), 100)
    for round_ in range(4):  # 50-byte entries: the second ends exactly at the circle's end
        buffer[:38] = bytes([round_]) * 38
        assert exact.put(round_, memoryview(buffer)[:38])
        assert exact.get() == (round_, bytes([round_]) * 38)


def test_a_full_ring_refuses_and_loses_nothing_it_took(tmp_path):
    ring = Ring(str(tmp_path / "r"), 100)
    assert ring.put(1, b"a" * 40)
    assert not ring.put(2, b"b" * 50)  # 52 + 62 bytes > 100: refused, and nothing of it written
    assert ring.free() == 48
    assert ring.get() == (1, b"a" * 40)
    assert ring.get() is None
    assert ring.put(3, b"c" * 80) and ring.get() == (3, b"c" * 80)


def test_a_corrupt_length_is_an_error_not_a_wild_read(tmp_path):
    ring = Ring(str(tmp_path / "r"), 100)
    ring.put(1, b"x")
    with open(tmp_path / "r", "r+b") as f:  # the entry header, just after the counters' line
        f.seek(64)
        f.write((10_000).to_bytes(4, "little"))
    with pytest.raises(RingError, match="claims 10000 bytes"):
        ring.get()


def _produce(path: str, count: int) -> None:
    ring = Ring(path)
    for i in range(count):
        payload = i.to_bytes(4, "little") * (1 + i % 50)
        while not ring.put(i, payload):
            pass  # full: wait for the consumer


def test_two_processes_pass_every_message_intact(tmp_path):
    path = str(tmp_path / "r")
    ring = Ring(path, 1 << 12)  # small, so the producer often finds it full
    count = 20_000
    producer = multiprocessing.get_context("spawn").Process(target=_produce, args=(path, count))
    producer.start()
    expected = 0
    while expected < count:
        entry = ring.get()
        if entry is None:
            assert producer.exitcode is None or ring.free() < ring.capacity, "the producer stopped early"
            continue
        tag, payload = entry
        assert tag == expected and payload == expected.to_bytes(4, "little") * (1 + expected % 50)
        expected += 1
    producer.join(10)
    assert producer.exitcode == 0


def test_discard_empties_the_ring_and_it_works_on(tmp_path):
    ring = Ring(str(tmp_path / "r"), 100)
    ring.put(1, b"a" * 30)
    ring.put(2, b"b" * 30)
    ring.discard()
    assert ring.get() is None and ring.free() == ring.capacity
    assert ring.put(3, b"c") and ring.get() == (3, b"c")
