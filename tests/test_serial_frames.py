"""The serial bridge's frames survive what a serial line does to them: split reads, garbage,
corrupted bytes, a sync pattern inside a payload; whatever is thrown away is counted."""
import random

import pytest

from hal import serial_frames as F


def test_a_frame_round_trips_and_its_crc_is_the_standard_ccitt_false():
    assert F.crc16(b"123456789") == 0x29B1  # the CRC catalogue's check value for CRC-16/CCITT-FALSE
    frame = F.encode(F.INPUTS, 513, [0, 1, 65535, 4096])
    assert F.FrameReader().feed(frame) == [F.Frame(F.INPUTS, 513, (0, 1, 65535, 4096))]


def test_frames_split_at_every_byte_and_run_together_are_all_found():
    frames = [F.encode(F.OUTPUTS, seq, [seq, 2 * seq]) for seq in range(50)]
    reader = F.FrameReader()
    got = [f for byte in b"".join(frames) for f in reader.feed(bytes([byte]))]
    assert [f.seq for f in got] == list(range(50)) and reader.stats.discarded_bytes == 0


def test_garbage_and_corrupted_frames_are_counted_and_the_good_ones_around_them_kept():
    rng = random.Random(7)
    good = [F.encode(F.INPUTS, seq, [seq] * 6) for seq in range(200)]
    stream, expected, corrupted = bytearray(), [], 0
    for seq, frame in enumerate(good):
        stream += bytes(rng.randrange(256) for _ in range(rng.randrange(5)))  # line noise
        if seq % 10 == 3:
            frame = bytearray(frame)
            frame[8] ^= 0x40  # one flipped bit in the payload
            corrupted += 1
        else:
            expected.append(seq)
        stream += frame
    reader = F.FrameReader()
    got = []
    while stream:  # reads of random sizes, as a port delivers them
        n = rng.randrange(1, 40)
        got += reader.feed(bytes(stream[:n]))
        del stream[:n]
    assert [f.seq for f in got] == expected
    assert reader.stats.crc_errors + reader.stats.bad_headers >= corrupted
    assert reader.stats.discarded_bytes > 0


def test_a_sync_pattern_inside_a_payload_does_not_cost_the_next_frame():
    tricky = F.encode(F.INPUTS, 1, [0x5AA5, 0x5AA5])  # the payload holds the sync bytes
    truncated = tricky[:-3]  # a frame cut short by a reset bridge
    reader = F.FrameReader()
    got = reader.feed(truncated + F.encode(F.INPUTS, 2, [7]) + tricky)
    assert [f.seq for f in got] == [2, 1]


@pytest.mark.parametrize("kind, seq, counts, text", [(0x02, 1, [1], "kind"), (F.OUTPUTS, 70000, [1], "uint16"),
                                                     (F.OUTPUTS, 1, [70000], "0..65535"),
                                                     (F.OUTPUTS, 1, [1] * 33, "at most 32")])
def test_what_the_protocol_cannot_carry_is_refused_when_encoding(kind, seq, counts, text):
    with pytest.raises(ValueError, match=text):
        F.encode(kind, seq, counts)


def test_a_header_with_an_impossible_length_is_skipped_not_waited_for():
    bogus = F.SYNC + bytes([F.INPUTS, 0, 0, 200])  # 200 bytes would exceed MAX_PAYLOAD
    reader = F.FrameReader()
    assert [f.seq for f in reader.feed(bogus + F.encode(F.INPUTS, 9, [1]))] == [9]
    assert reader.stats.bad_headers == 1
