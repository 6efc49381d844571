"""The assumed PPS frame layout: encoding, byte offsets, and the streaming decoder under fuzzing
(random bytes; valid frames among garbage, truncated and corrupted frames, in random chunks)."""

import functools
import struct

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from twin.hardware.pps.frame import (
    FRAME_SIZE,
    SYNC,
    Frame,
    FrameDecoder,
    crc16_ccitt_false,
    decode_frame,
    encode_frame,
)

from twin.interface.devices import N_TAXELS

FUZZ = settings(
    max_examples=10_000,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
COUNTS = (np.arange(N_TAXELS) * 203) % 32768


def test_crc_is_ccitt_false():
    assert crc16_ccitt_false(b"123456789") == 0x29B1  # the catalogue's check value


def test_layout_offsets():
    raw = encode_frame(0x1234, 0x89ABCDEF, COUNTS)
    assert len(raw) == FRAME_SIZE == 336
    assert raw[:2] == b"\xa5\x5a"
    assert struct.unpack_from(">H", raw, 2)[0] == 0x1234
    assert struct.unpack_from(">I", raw, 4)[0] == 0x89ABCDEF
    assert struct.unpack_from(">H", raw, 8)[0] == N_TAXELS
    assert list(struct.unpack_from(">162H", raw, 10)) == COUNTS.tolist()
    assert struct.unpack_from(">H", raw, 334)[0] == crc16_ccitt_false(raw[2:334])


def test_round_trip_and_wrapping():
    frame = decode_frame(encode_frame(65536 + 7, 2**32 + 5, COUNTS))
    assert frame is not None and (frame.sequence, frame.timestamp_us) == (7, 5)
    assert frame.counts.dtype == np.int32 and np.array_equal(frame.counts, COUNTS)
    extremes = np.array([0, 32767] * 81)
    assert np.array_equal(decode_frame(encode_frame(0, 0, extremes)).counts, extremes)


@pytest.mark.parametrize(
    "counts",
    [np.zeros(161, int), np.zeros((2, 81), int), np.full(162, 32768), np.full(162, -1), np.zeros(162)],
)
def test_encode_refuses_what_is_not_162_fifteen_bit_integers(counts):
    with pytest.raises(ValueError):
        encode_frame(0, 0, counts)


def test_each_check_rejects():
    good = bytearray(encode_frame(1, 2, COUNTS))
    bad_count = bytearray(good)
    bad_count[9] = 161
    bad_crc = bytearray(good)
    bad_crc[-1] ^= 0xFF
    top_bit = bytearray(
        good
    )  # a count with its 16th bit set, the CRC fixed up: only the 15-bit check catches it
    top_bit[10] |= 0x80
    top_bit[-2:] = struct.pack(">H", crc16_ccitt_false(bytes(top_bit[2:-2])))
    for raw in (bad_count, bad_crc, top_bit, good[:-1], b"\x00" + good[1:]):
        assert decode_frame(bytes(raw)) is None
    assert decode_frame(bytes(good)) is not None


def test_decoder_byte_by_byte_and_sync_split_across_chunks():
    stream = b"\xa5" + encode_frame(3, 30, COUNTS) + b"\x5a\xa5" + encode_frame(4, 40, COUNTS) + b"\xa5"
    decoder = FrameDecoder()
    frames = [f for i in range(len(stream)) for f in decoder.feed(stream[i : i + 1])]
    assert [f.sequence for f in frames] == [3, 4]
    assert decoder.discarded_bytes == 3 and decoder.buffered == 1 and decoder.bad_frames == 0


def test_decoder_misuse():
    with pytest.raises(TypeError):
        FrameDecoder().feed("text")  # type: ignore[arg-type]


# --- fuzzing ------------------------------------------------------------------------------------
# Each example is one byte string read as a small program (opcodes and their parameters): one draw per
# example keeps 10,000 examples cheap, and Hypothesis still shrinks a failure to a short program.

TAXEL_INDEX = np.arange(N_TAXELS, dtype=np.uint64)
MASK32 = np.uint64(0xFFFFFFFF)
SYNC_LADEN_TOKENS = (SYNC, b"\xa5", b"\x00\xa2", b"\x13", b"\x5a")


class _Program:
    """Reads parameters off the fuzz bytes; zeros once they run out."""

    def __init__(self, blob: bytes) -> None:
        self.blob, self.pos = blob, 0

    def left(self) -> bool:
        return self.pos < len(self.blob)

    def take(self, n: int) -> bytes:
        out = self.blob[self.pos : self.pos + n]
        self.pos += n
        return out

    def uint(self, nbytes: int) -> int:
        return int.from_bytes(self.take(nbytes).ljust(nbytes, b"\0"), "big")


@functools.cache
def _counts(seed: int) -> np.ndarray:
    """Pseudo-random 15-bit counts from a byte; odd seeds plant false syncs (A5 5A) in the payload."""
    x = (TAXEL_INDEX * np.uint64(0x9E3779B1) + np.uint64(seed) * np.uint64(0x85EBCA77)) & MASK32
    x ^= x >> np.uint64(15)
    x = (x * np.uint64(0x2C1B3C6D)) & MASK32
    x ^= x >> np.uint64(12)
    counts = (x & np.uint64(0x7FFF)).astype(np.int32)
    if seed & 1:
        counts[0:-1:7] = (counts[0:-1:7] & 0x7F00) | 0xA5
        counts[1::7] = 0x5A00 | (counts[1::7] & 0xFF)
    return counts


def _frame(p: _Program) -> Frame:
    """Three program bytes: the sequence and a seed for the counts and the timestamp."""
    sequence, seed = p.uint(2), p.uint(1)
    return Frame(sequence, (seed * 0x01000193 + sequence) % 2**32, _counts(seed))


def _raw(frame: Frame) -> bytes:
    return encode_frame(frame.sequence, frame.timestamp_us, frame.counts)


def _chunk_sizes(p: _Program) -> list[int]:
    return [1 + p.uint(2) % (2 * FRAME_SIZE) for _ in range(1 + p.uint(1) % 8)]


def _stream(p: _Program) -> tuple[bytes, list[Frame], set[str], list[int]]:
    """Valid frames (half the items) among garbage, sync-laden garbage, truncated and corrupted frames;
    also where each damaged frame starts."""
    out, valid, kinds, damaged = bytearray(), [], set(), []
    while p.left():
        op = p.uint(1) % 8
        if op == 0:
            kinds.add("garbage")
            out += p.take(p.uint(1) % 24)
        elif op == 1:
            kinds.add("sync-laden garbage")
            word = p.uint(2)
            for _ in range(7):
                word, token = divmod(word, len(SYNC_LADEN_TOKENS))
                out += SYNC_LADEN_TOKENS[token]
        else:
            frame = _frame(p)
            raw = bytearray(_raw(frame))
            if op in (2, 3):
                damaged.append(len(out))
            if op == 2:
                kinds.add("truncated")
                raw = raw[: 1 + p.uint(2) % (FRAME_SIZE - 1)]
            elif op == 3:
                kinds.add("corrupted")
                raw[p.uint(2) % FRAME_SIZE] ^= 1 + p.uint(1) % 255
            else:
                valid.append(frame)
            out += raw
    return bytes(out), valid, kinds, damaged


def _feed_in_chunks(decoder: FrameDecoder, data: bytes, sizes: list[int]) -> list[Frame]:
    got, i, k = [], 0, 0
    while i < len(data):
        size = sizes[k % len(sizes)]
        got += decoder.feed(data[i : i + size])
        i, k = i + size, k + 1
    return got


def _accounted(decoder: FrameDecoder, total: int) -> bool:
    """Every byte fed is in a frame, discarded, or still buffered."""
    return decoder.frames * FRAME_SIZE + decoder.discarded_bytes + decoder.buffered == total


@pytest.mark.slow
@FUZZ
@given(st.binary(max_size=2000))
def test_fuzz_random_bytes_only_yield_genuine_frames(blob):
    """Noise never raises, and whatever the decoder returns is a frame whose exact bytes were there."""
    p = _Program(blob)
    sizes = _chunk_sizes(p)
    data = p.take(len(blob))
    decoder = FrameDecoder()
    got = _feed_in_chunks(decoder, data, sizes)
    assert all(_raw(f) in data for f in got)
    assert _accounted(decoder, len(data)) and decoder.buffered < FRAME_SIZE


def test_the_stream_program_reaches_every_item_kind():
    program = (
        b"\x00\x00\x00"  # one chunk size: 1 byte
        + b"\x00\x03abc"  # garbage
        + b"\x01\x12\x34"  # sync-laden garbage
        + b"\x04\x00\x01\x03"  # valid, sequence 1
        + b"\x02\x00\x02\x05\x00\xa0"  # truncated to 161 bytes
        + b"\x05\x00\x03\x07"  # valid
        + b"\x03\x00\x04\x09\x00\x20\x07"  # corrupted at byte 32
        + b"\x07\x00\x05\x0b"  # valid
    )  # fmt: skip
    data, valid, kinds, _ = _stream(_Program(program[3:]))
    assert [f.sequence for f in valid] == [1, 3, 5]
    assert kinds == {"garbage", "sync-laden garbage", "truncated", "corrupted"}
    got = _feed_in_chunks(FrameDecoder(), data, _chunk_sizes(_Program(program)))
    assert [f.sequence for f in got] == [1, 3, 5]


@pytest.mark.slow
@FUZZ
@given(st.binary(min_size=48, max_size=600))
def test_fuzz_every_valid_frame_survives_garbage_truncation_and_corruption(blob):
    """Every valid frame comes out exactly (sequence, timestamp, counts), in order; nothing else does."""
    p = _Program(blob)
    sizes = _chunk_sizes(p)
    data, valid, kinds, damaged = _stream(p)
    # A truncated frame can be completed by what follows it (a cut CRC byte 0xA5, then a sync): then
    # the stream really holds that frame, so the example is not what it claims to be.
    assume(all(decode_frame(data[i : i + FRAME_SIZE]) is None for i in damaged))
    decoder = FrameDecoder()
    got = _feed_in_chunks(decoder, data, sizes)
    assert [(f.sequence, f.timestamp_us) for f in got] == [(f.sequence, f.timestamp_us) for f in valid]
    assert all(np.array_equal(g.counts, v.counts) for g, v in zip(got, valid, strict=True))
    assert _accounted(decoder, len(data))
    if not kinds:
        assert decoder.discarded_bytes == 0 and decoder.bad_frames == 0 and decoder.buffered == 0


@pytest.mark.slow
@FUZZ
@given(st.binary(min_size=18, max_size=64))
def test_fuzz_encode_round_trips_or_refuses(blob):
    """encode_frame either raises ValueError (misuse) or produces a frame that decodes to its input."""
    sequence = int.from_bytes(blob[:8], "big", signed=True)  # any int: it wraps
    timestamp_us = int.from_bytes(blob[8:16], "big", signed=True)
    n = N_TAXELS - 2 + blob[16] % 4  # 160-163 values, tiled from the rest
    mask = 0x7FFF if blob[17] % 2 else 0xFFFF  # about half the examples are in range
    words = np.frombuffer(blob[18:][: (len(blob) - 18) // 2 * 2] or b"\0\0", ">u2").astype(np.int64)
    values = (np.resize(words, n) & mask) - (blob[17] >> 7)  # and some go negative
    try:
        encoded = encode_frame(sequence, timestamp_us, values)
    except ValueError:
        assert values.shape != (N_TAXELS,) or values.min() < 0 or values.max() > 32767
        return
    frame = decode_frame(encoded)
    assert frame is not None and frame.sequence == sequence % 65536
    assert frame.timestamp_us == timestamp_us % 2**32 and np.array_equal(frame.counts, values)
