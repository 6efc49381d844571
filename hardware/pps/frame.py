"""The PPS tactile frame on the wire: the one place that knows the byte layout.

The RoboTouch interface's wire format is not public (hardware_facts §4), so this layout is OUR
ASSUMPTION, shared by the driver and the emulator. A lab with the vendor's documentation adapts
`encode_frame` and `FrameDecoder` here and nothing else. All integers are big-endian:

    offset  size  field
         0     2  sync: 0xA5 0x5A
         2     2  sequence, uint16 (wraps 65535 -> 0)
         4     4  device timestamp in microseconds, uint32 (wraps after ~71.6 min)
         8     2  taxel count, uint16 (= 162)
        10   324  162 taxel counts, uint16 each, top bit 0 (15-bit, 0-32767), in taxel-id order
       334     2  CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF) of bytes 2-333, uint16
       336        frame size

`FrameDecoder` reads a byte stream in any chunking: it searches for the sync, checks the taxel count,
the 15-bit counts and the CRC, and on a bad candidate drops only its first byte and searches again, so
a valid frame that follows garbage, a truncated frame or a corrupted frame is never lost.
"""

from __future__ import annotations

import binascii
import struct
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from twin.interface.devices import N_TAXELS, TAXEL_COUNT_MAX

SYNC = b"\xa5\x5a"
HEADER = struct.Struct(">2sHIH")  # sync, sequence, timestamp_us, taxel count
HEADER_SIZE = HEADER.size  # 10
PAYLOAD_SIZE = 2 * N_TAXELS  # 324
CRC_SIZE = 2
FRAME_SIZE = HEADER_SIZE + PAYLOAD_SIZE + CRC_SIZE  # 336
SEQUENCE_MODULO = 1 << 16
TIMESTAMP_MODULO = 1 << 32
CRC_INIT = 0xFFFF


def crc16_ccitt_false(data: bytes) -> int:
    """CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no final xor); b"123456789" -> 0x29B1."""
    return binascii.crc_hqx(data, CRC_INIT)


@dataclass(frozen=True)
class Frame:
    """One decoded scan: the device's sequence number and timestamp, and the 162 raw counts."""

    sequence: int
    timestamp_us: int
    counts: NDArray[np.int32]


def encode_frame(sequence: int, timestamp_us: int, counts: ArrayLike) -> bytes:
    """One frame's bytes; sequence and timestamp wrap; ValueError unless 162 counts in 0-32767."""
    values = np.asarray(counts)
    if values.shape != (N_TAXELS,):
        raise ValueError(f"a frame carries {N_TAXELS} counts, got shape {values.shape}")
    if not np.issubdtype(values.dtype, np.integer):
        raise ValueError(f"counts must be integers, got {values.dtype}")
    if values.min() < 0 or values.max() > TAXEL_COUNT_MAX:
        raise ValueError(f"counts must be 15-bit (0-{TAXEL_COUNT_MAX}), got {values.min()}..{values.max()}")
    body = HEADER.pack(SYNC, sequence % SEQUENCE_MODULO, timestamp_us % TIMESTAMP_MODULO, N_TAXELS)
    body += values.astype(">u2").tobytes()
    return body + struct.pack(">H", crc16_ccitt_false(body[len(SYNC) :]))


def decode_frame(raw: bytes) -> Frame | None:
    """The frame in exactly FRAME_SIZE bytes, or None if any check fails (sync, count, 15 bit, CRC)."""
    if len(raw) != FRAME_SIZE:
        return None
    sync, sequence, timestamp_us, n_taxels = HEADER.unpack_from(raw)
    if sync != SYNC or n_taxels != N_TAXELS:
        return None
    (crc,) = struct.unpack_from(">H", raw, FRAME_SIZE - CRC_SIZE)
    if crc != crc16_ccitt_false(raw[len(SYNC) : FRAME_SIZE - CRC_SIZE]):
        return None
    counts = np.frombuffer(raw, dtype=">u2", count=N_TAXELS, offset=HEADER_SIZE)
    if counts.max() > TAXEL_COUNT_MAX:
        return None
    return Frame(sequence, timestamp_us, counts.astype(np.int32))


class FrameDecoder:
    """Frames out of a byte stream fed in arbitrary chunks, resynchronising on the sync after any damage.

    Bytes that belong to no valid frame are counted in `discarded_bytes`; each candidate that started
    with the sync but failed a check is counted in `bad_frames` (garbage that happens to contain the
    sync counts too, so lost frames are better counted from sequence gaps).
    """

    def __init__(self) -> None:
        self._buffer = bytearray()
        self.frames = 0
        """Valid frames decoded so far."""
        self.bad_frames = 0
        """Candidates that began with the sync but failed the taxel count, 15-bit or CRC check."""
        self.discarded_bytes = 0
        """Bytes dropped while searching for the next valid frame."""

    @property
    def buffered(self) -> int:
        """Bytes held back: the start of a frame (or of its sync) still incomplete."""
        return len(self._buffer)

    @property
    def needed(self) -> int:
        """Fewest bytes that could complete the next frame: read this many for the lowest latency."""
        return max(1, FRAME_SIZE - len(self._buffer))

    def feed(self, data: bytes) -> list[Frame]:
        """Add bytes; returns the frames they complete, in stream order (TypeError if not bytes-like)."""
        buf = self._buffer
        buf += data
        frames: list[Frame] = []
        while True:
            start = buf.find(SYNC)
            if start < 0:
                keep = 1 if buf[-1:] == SYNC[:1] else 0  # a sync cut between chunks
                self._discard(len(buf) - keep)
                return frames
            self._discard(start)
            if len(buf) < FRAME_SIZE:
                return frames
            frame = decode_frame(bytes(buf[:FRAME_SIZE]))
            if frame is None:
                self.bad_frames += 1
                self._discard(1)  # a valid frame may begin inside this candidate
                continue
            del buf[:FRAME_SIZE]
            self.frames += 1
            frames.append(frame)

    def _discard(self, n: int) -> None:
        if n > 0:
            del self._buffer[:n]
            self.discarded_bytes += n

    def reset(self) -> None:
        """Forget buffered bytes (after flushing the port); the counters stay."""
        self._buffer.clear()
