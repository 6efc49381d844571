"""The assumed PPS frame layout: encoding, byte offsets, and the streaming decoder under fuzzing
(random bytes; valid frames among garbage, truncated and corrupted frames, in random chunks)."""

import struct

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hardware.pps.frame import (
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

frames = st.builds(
    lambda seq, ts, raw: Frame(seq, ts, (np.frombuffer(raw, ">u2") & 0x7FFF).astype(np.int32)),
    st.integers(0, 65535),
    st.integers(0, 2**32 - 1),
    st.binary(min_size=2 * N_TAXELS, max_size=2 * N_TAXELS),
)


def _raw(frame: Frame) -> bytes:
    return encode_frame(frame.sequence, frame.timestamp_us, frame.counts)


items = st.one_of(
    st.tuples(st.just("valid"), frames),
    st.tuples(st.just("garbage"), st.binary(min_size=1, max_size=400)),
    st.tuples(
        st.just("sync-laden garbage"), st.lists(st.sampled_from([SYNC, b"\xa5", b"\x00\xa2", b"\x13"]))
    ),
    st.tuples(st.just("truncated"), frames, st.integers(1, FRAME_SIZE - 1)),
    st.tuples(st.just("corrupted"), frames, st.integers(0, FRAME_SIZE - 1), st.integers(1, 255)),
)
chunkings = st.lists(st.integers(1, 2 * FRAME_SIZE), min_size=1, max_size=8)


def _build(stream_items) -> tuple[bytes, list[Frame]]:
    out, valid = bytearray(), []
    for item in stream_items:
        kind = item[0]
        if kind == "valid":
            out += _raw(item[1])
            valid.append(item[1])
        elif kind == "garbage":
            out += item[1]
        elif kind == "sync-laden garbage":
            out += b"".join(item[1])
        elif kind == "truncated":
            out += _raw(item[1])[: item[2]]
        else:
            raw = bytearray(_raw(item[1]))
            raw[item[2]] ^= item[3]
            out += raw
    return bytes(out), valid


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


@FUZZ
@given(st.binary(max_size=2000), chunkings)
def test_fuzz_random_bytes_only_yield_genuine_frames(data, sizes):
    """Noise never raises, and whatever the decoder returns is a frame whose exact bytes were there."""
    decoder = FrameDecoder()
    got = _feed_in_chunks(decoder, data, sizes)
    assert all(_raw(f) in data for f in got)
    assert _accounted(decoder, len(data)) and decoder.buffered < FRAME_SIZE


@FUZZ
@given(st.lists(items, max_size=10), chunkings)
def test_fuzz_every_valid_frame_survives_garbage_truncation_and_corruption(stream_items, sizes):
    """Every valid frame comes out exactly (sequence, timestamp, counts), in order; nothing else does."""
    data, valid = _build(stream_items)
    decoder = FrameDecoder()
    got = _feed_in_chunks(decoder, data, sizes)
    assert [(f.sequence, f.timestamp_us) for f in got] == [(f.sequence, f.timestamp_us) for f in valid]
    assert all(np.array_equal(g.counts, v.counts) for g, v in zip(got, valid, strict=True))
    assert _accounted(decoder, len(data))
    if all(kind == "valid" for kind, *_ in stream_items):
        assert decoder.discarded_bytes == 0 and decoder.bad_frames == 0


@FUZZ
@given(
    st.binary(min_size=2 * (N_TAXELS - 2), max_size=2 * (N_TAXELS + 1)),
    st.sampled_from([0x7FFF, 0xFFFF]),
    st.integers(0, 1),
    st.integers(),
    st.integers(),
)
def test_fuzz_encode_round_trips_or_refuses(raw, mask, shift, sequence, timestamp_us):
    """encode_frame either raises ValueError (misuse) or produces a frame that decodes to its input."""
    values = (np.frombuffer(raw[: len(raw) // 2 * 2], ">u2").astype(np.int64) & mask) - shift
    try:
        encoded = encode_frame(sequence, timestamp_us, values)
    except ValueError:
        assert values.shape != (N_TAXELS,) or values.min() < 0 or values.max() > 32767
        return
    frame = decode_frame(encoded)
    assert frame is not None and frame.sequence == sequence % 65536
    assert frame.timestamp_us == timestamp_us % 2**32 and np.array_equal(frame.counts, values)
