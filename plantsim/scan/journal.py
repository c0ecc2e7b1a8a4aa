"""An append-only scan journal: one checksummed record per completed scan line.

A rig scan writes each line to disk as soon as it is taken, so that a fault, a
power cut or Ctrl-C loses at most the line in flight, and ``--resume`` continues
from the last complete line. The final cloud is built from the journal, so every
line is in it exactly once.

File layout: a sequence of frames, each

    magic b"PSJ1" | payload length (uint32 LE) | zlib.crc32(payload) (uint32 LE) | payload

The first frame's payload is the header, UTF-8 JSON: the scan's identity (the
resolved configuration that determines the lines, and a hash of it), the number of
lines and beams, and the wall-clock start. Every further frame is one
:class:`JournalLine` (:meth:`JournalLine.to_bytes`), or a chunk of turntable encoder
readings (:func:`encode_encoder_chunk`: payload ``b"ENC2"`` | count (uint32 LE) | host
clock before each read, the device's clock, host clock after (int64 ns) | angles (float64
rad) | run (int32); continuous rig scans, whose table is read on its own clock: the
readings' times are derived from these when the raw record is built). A line record's first 4 bytes are its index, never ``ENC2`` (that index
would be above 800 million). Each frame is written with one
``write`` and then ``fsync``-ed. A crash can only tear the last frame; reading drops
a torn tail (short, or failing its checksum) and logs it. A bad frame *followed by*
a good one is damage, not a tear, and raises :class:`~plantsim.errors.JournalError`.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import os
import struct
import zlib
from pathlib import Path

import numpy as np

from plantsim.errors import JournalError

log = logging.getLogger(__name__)

MAGIC = b"PSJ1"
FORMAT_VERSION = 2
_FRAME = struct.Struct("<4sII")  # magic, payload length, crc32 of the payload
# Line record head: index, n_beams, commanded, reported and cast angle (rad), line stamp
# (ns since the scan's start), whether intensities follow.
_LINE = struct.Struct("<IIdddqB")
_MAX_PAYLOAD = 1 << 28  # a sanity bound on a frame's length field (256 MiB)
ENCODER_MAGIC = b"ENC2"
#: The fields of an encoder-readings record, each an array of one value per reading.
ENCODER_FIELDS = (("sent_ns", "<i8"), ("device_ns", "<i8"), ("received_ns", "<i8"), ("angle_rad", "<f8"),
                  ("run", "<i4"))


def encode_encoder_chunk(readings: dict) -> bytes:
    """The payload of an encoder-readings record.

    Args:
      readings: equal-length 1-D arrays: ``sent_ns`` and ``received_ns`` (the host
        clock before and after the read, ns since the scan's start), ``device_ns``
        (the device's own clock at the reading, ns, unwrapped; its epoch is the run's),
        ``angle_rad`` (the reading) and ``run`` (which run of a resumed scan took it).
    """
    arrays = [np.ascontiguousarray(readings[name], dtype=dtype) for name, dtype in ENCODER_FIELDS]
    n = len(arrays[0])
    if any(a.shape != (n,) for a in arrays):
        raise ValueError(f"encoder readings must be equal-length 1-D arrays, got {[a.shape for a in arrays]}")
    return ENCODER_MAGIC + struct.pack("<I", n) + b"".join(a.tobytes() for a in arrays)


def decode_encoder_chunk(payload: bytes) -> dict:
    """The arrays of an encoder-readings record (see :func:`encode_encoder_chunk`).

    Raises:
      JournalError: the record's length does not match its count.
    """
    (n,) = struct.unpack_from("<I", payload, len(ENCODER_MAGIC))
    offset = len(ENCODER_MAGIC) + 4
    size = sum(np.dtype(dtype).itemsize for _, dtype in ENCODER_FIELDS)
    if len(payload) != offset + size * n:
        raise JournalError(f"an encoder record has {len(payload)} bytes, expected {offset + size * n} for "
                           f"{n} readings")
    out = {}
    for name, dtype in ENCODER_FIELDS:
        out[name] = np.frombuffer(payload, dtype=dtype, count=n, offset=offset).astype(np.dtype(dtype).newbyteorder("="))
        offset += np.dtype(dtype).itemsize * n
    return out


def concat_encoder(chunks: list[dict]) -> dict:
    """One dict of arrays from encoder chunks (empty arrays when there are none)."""
    return {name: (np.concatenate([c[name] for c in chunks]) if chunks
                   else np.empty(0, np.dtype(dtype).newbyteorder("=")))
            for name, dtype in ENCODER_FIELDS}


def identity_hash(identity: dict) -> str:
    """SHA-256 of the identity's canonical JSON (sorted keys, no spaces; inf as Infinity)."""
    text = json.dumps(identity, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


@dataclasses.dataclass(frozen=True, eq=False)
class JournalLine:
    """One completed scan line.

    Attributes:
      index: the line's index in the schedule (0-based).
      commanded_angle_rad: the angle the turntable was sent to, rad.
      reported_angle_rad: the angle the turntable reported after the move, rad
        (the reconstruction uses this one).
      cast_angle_rad: where the simulated LiDAR cast its rays, rad (NaN for a real sensor).
      stamp_ns: the line's first beam, nanoseconds since the scan's start.
      range_m: (n_beams,) float64, metres, NaN where there is no return.
      status: (n_beams,) uint8 :class:`~plantsim.sensor.BeamStatus`.
      hit_class: (n_beams,) uint8 :class:`~plantsim.scene.HitClass`.
      geom_id: (n_beams,) int32, MuJoCo geom id or -1.
      intensity: (n_beams,) float32 or None.
    """

    index: int
    commanded_angle_rad: float
    reported_angle_rad: float
    cast_angle_rad: float
    stamp_ns: int
    range_m: np.ndarray
    status: np.ndarray
    hit_class: np.ndarray
    geom_id: np.ndarray
    intensity: np.ndarray | None = None

    def __post_init__(self):
        n = len(self.range_m)
        for name in ("status", "hit_class", "geom_id"):
            if len(getattr(self, name)) != n:
                raise ValueError(f"{name} must have {n} beams like range_m, got {len(getattr(self, name))}")

    def to_bytes(self) -> bytes:
        head = _LINE.pack(self.index, len(self.range_m), self.commanded_angle_rad,
                          self.reported_angle_rad, self.cast_angle_rad, int(self.stamp_ns),
                          self.intensity is not None)
        parts = [head, np.ascontiguousarray(self.range_m, dtype="<f8").tobytes(),
                 np.ascontiguousarray(self.status, dtype=np.uint8).tobytes(),
                 np.ascontiguousarray(self.hit_class, dtype=np.uint8).tobytes(),
                 np.ascontiguousarray(self.geom_id, dtype="<i4").tobytes()]
        if self.intensity is not None:
            parts.append(np.ascontiguousarray(self.intensity, dtype="<f4").tobytes())
        return b"".join(parts)

    @classmethod
    def from_bytes(cls, payload: bytes) -> "JournalLine":
        index, n, commanded, reported, cast, stamp_ns, has_intensity = _LINE.unpack_from(payload)
        expected = _LINE.size + n * (8 + 1 + 1 + 4 + (4 if has_intensity else 0))
        if len(payload) != expected:
            raise JournalError(f"line record {index} has {len(payload)} bytes, expected "
                               f"{expected} for {n} beams")
        offset = _LINE.size
        arrays = []
        fields = [("<f8", 8), (np.uint8, 1), (np.uint8, 1), ("<i4", 4)] + ([("<f4", 4)] if has_intensity else [])
        for dtype, size in fields:
            arrays.append(np.frombuffer(payload, dtype=dtype, count=n, offset=offset).copy())
            offset += n * size
        return cls(index=index, commanded_angle_rad=commanded, reported_angle_rad=reported,
                   cast_angle_rad=cast, stamp_ns=stamp_ns, range_m=arrays[0].astype(np.float64),
                   status=arrays[1], hit_class=arrays[2], geom_id=arrays[3].astype(np.int32),
                   intensity=arrays[4].astype(np.float32) if has_intensity else None)


def encode_frame(payload: bytes) -> bytes:
    """One self-delimiting, checksummed frame."""
    return _FRAME.pack(MAGIC, len(payload), zlib.crc32(payload)) + payload


def _frame_at(data: bytes, offset: int) -> bytes | None:
    """The payload of a valid frame at ``offset``, or None."""
    if len(data) - offset < _FRAME.size:
        return None
    magic, length, crc = _FRAME.unpack_from(data, offset)
    end = offset + _FRAME.size + length
    if magic != MAGIC or length > _MAX_PAYLOAD or end > len(data):
        return None
    payload = data[offset + _FRAME.size:end]
    return payload if zlib.crc32(payload) == crc else None


def split_frames(data: bytes, *, source: str = "journal") -> tuple[list[bytes], int]:
    """Splits a journal's bytes into frame payloads.

    Returns:
      (payloads, valid_length): the payloads of the valid frames, and the byte
      length they span; bytes after ``valid_length`` are a torn tail.

    Raises:
      JournalError: if a bad frame is followed by a valid one (damage, not a tear).
    """
    payloads, offset = [], 0
    while offset < len(data):
        payload = _frame_at(data, offset)
        if payload is None:
            break
        payloads.append(payload)
        offset += _FRAME.size + len(payload)
    if offset < len(data):
        later = data.find(MAGIC, offset + 1)
        while later != -1:
            if _frame_at(data, later) is not None:
                raise JournalError(
                    f"{source} is damaged: a bad record at byte {offset} is followed by valid ones; "
                    "it was not written by an interrupted scan. Delete it to scan again from the start.")
            later = data.find(MAGIC, later + 1)
    return payloads, offset


@dataclasses.dataclass(frozen=True, eq=False)
class JournalContents:
    """What a journal holds.

    Attributes:
      header: the header's JSON, or None if even the header frame was torn.
      lines: the complete line records, in order (``lines[i].index == i``).
      valid_length: bytes of valid frames; the file may hold a torn tail after it.
      torn_bytes: length of the torn tail that was dropped.
      encoder: the encoder readings journaled (continuous rig scans; empty arrays
        otherwise), in order: :func:`encode_encoder_chunk`'s arrays.
    """

    header: dict | None
    lines: list[JournalLine]
    valid_length: int
    torn_bytes: int
    encoder: dict = dataclasses.field(default_factory=lambda: concat_encoder([]))


def read_journal(path: str | os.PathLike) -> JournalContents:
    """Reads a journal, dropping a torn last record.

    Raises:
      FileNotFoundError: no journal at ``path``.
      JournalError: damaged, not a plantsim journal, or records out of order.
    """
    path = Path(path)
    data = path.read_bytes()
    if data and not data.startswith(MAGIC[: min(len(data), len(MAGIC))]):
        raise JournalError(f"{path} is not a plantsim scan journal; move it away or delete it")
    payloads, valid = split_frames(data, source=str(path))
    torn = len(data) - valid
    if torn:
        log.warning("%s: dropped a torn last record (%d bytes) left by an interrupted write", path, torn)
    if not payloads:
        return JournalContents(header=None, lines=[], valid_length=0, torn_bytes=torn)
    try:
        header = json.loads(payloads[0].decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise JournalError(f"{path}: its header is not valid JSON ({exc}); delete it to start over") from exc
    if not isinstance(header, dict) or header.get("plantsim_journal") != FORMAT_VERSION:
        raise JournalError(f"{path}: unsupported journal version "
                           f"{header.get('plantsim_journal') if isinstance(header, dict) else header!r}, "
                           f"expected {FORMAT_VERSION}")
    lines, chunks = [], []
    for payload in payloads[1:]:
        if payload[:len(ENCODER_MAGIC)] == ENCODER_MAGIC:
            chunks.append(decode_encoder_chunk(payload))
            continue
        position = len(lines)
        line = JournalLine.from_bytes(payload)
        if line.index != position:
            raise JournalError(f"{path}: record {position} holds line {line.index}; lines must be "
                               "journaled in order, each once. Delete the journal to start over.")
        if len(line.range_m) != header.get("n_beams"):
            raise JournalError(f"{path}: line {line.index} has {len(line.range_m)} beams, the header "
                               f"says {header.get('n_beams')}")
        lines.append(line)
    return JournalContents(header=header, lines=lines, valid_length=valid, torn_bytes=torn,
                           encoder=concat_encoder(chunks))


def _differences(a, b, prefix: str = "") -> list[str]:
    """Dotted keys where two nested dicts differ."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for key in sorted(set(a) | set(b)):
            out += _differences(a.get(key), b.get(key), f"{prefix}{key}.")
        return out
    return [] if a == b else [prefix.rstrip(".")]


class Journal:
    """An open journal that lines are appended to. Use :meth:`create` or :meth:`resume`.

    Attributes:
      path: the file.
      header: its header.
      lines: the lines journaled so far (resumed and new), in order.
      lines_resumed: lines the journal held when it was opened.
      encoder_chunks: the encoder readings journaled (resumed and new), in order.
    """

    def __init__(self, path: Path, handle, header: dict, lines: list[JournalLine], encoder: dict | None = None):
        self.path = path
        self._handle = handle
        self.header = header
        self.lines = lines
        self.lines_resumed = len(lines)
        self.encoder_chunks: list[dict] = [encoder] if encoder is not None and len(encoder["angle_rad"]) else []

    @staticmethod
    def make_header(identity: dict, *, n_lines: int, n_beams: int, started_unix_s: float) -> dict:
        # As it will read back (tuples become lists), so stored and new compare key by key.
        identity = json.loads(json.dumps(identity, sort_keys=True))
        return {"plantsim_journal": FORMAT_VERSION, "identity_sha256": identity_hash(identity),
                "n_lines": int(n_lines), "n_beams": int(n_beams),
                "started_unix_s": float(started_unix_s), "identity": identity}

    @classmethod
    def create(cls, path: str | os.PathLike, header: dict) -> "Journal":
        """Starts a new journal; refuses to overwrite one.

        Raises:
          JournalError: a journal is already there (resume it or delete it).
        """
        path = Path(path)
        try:
            handle = open(path, "xb")
        except FileExistsError:
            raise JournalError(
                f"a journal of an unfinished scan exists at {path}; pass --resume (resume=True) to "
                "continue it, or delete it to start over") from None
        journal = cls(path, handle, header, [])
        journal._write(json.dumps(header, sort_keys=True).encode("utf-8"))
        _fsync_dir(path.parent)
        return journal

    @classmethod
    def resume(cls, path: str | os.PathLike, header: dict) -> "Journal":
        """Opens an existing journal to continue it, dropping a torn last record.

        Args:
          path: the journal.
          header: the header this scan would write (:meth:`make_header`); the
            journal's identity must match it.

        Raises:
          FileNotFoundError: no journal at ``path``.
          JournalError: the journal is damaged or was written for another
            configuration (the message names the differing settings).
        """
        path = Path(path)
        contents = read_journal(path)
        stored = contents.header
        if stored is None:
            log.warning("%s holds no complete header; starting it again", path)
            path.unlink()
            return cls.create(path, header)
        if stored.get("identity_sha256") != header["identity_sha256"]:
            changed = _differences(stored.get("identity", {}), header["identity"])
            raise JournalError(
                f"{path} was written for another configuration (differs in: "
                f"{', '.join(changed) or 'identity hash'}); resume with the settings it was written "
                "for, or delete it to start over")
        if stored.get("n_lines") != header["n_lines"] or stored.get("n_beams") != header["n_beams"]:
            raise JournalError(f"{path}: header has {stored.get('n_lines')} lines x {stored.get('n_beams')} "
                               f"beams, this scan {header['n_lines']} x {header['n_beams']}")
        if len(contents.lines) > stored["n_lines"]:
            raise JournalError(f"{path} holds {len(contents.lines)} lines, more than the scan's "
                               f"{stored['n_lines']}; delete it to start over")
        handle = open(path, "r+b")
        if contents.torn_bytes:
            handle.truncate(contents.valid_length)
            os.fsync(handle.fileno())
        handle.seek(contents.valid_length)
        return cls(path, handle, stored, list(contents.lines), encoder=contents.encoder)

    def _write(self, payload: bytes) -> None:
        self._handle.write(encode_frame(payload))
        self._handle.flush()
        os.fsync(self._handle.fileno())

    def append(self, line: JournalLine) -> None:
        """Appends one line and fsyncs it.

        Raises:
          ValueError: if the line is not the next one (``line.index != len(lines)``).
        """
        if line.index != len(self.lines):
            raise ValueError(f"line.index must be the next line, {len(self.lines)}, got {line.index}")
        self._write(line.to_bytes())
        self.lines.append(line)

    def append_encoder(self, readings: dict) -> None:
        """Appends encoder readings (:func:`encode_encoder_chunk`'s arrays) and fsyncs them."""
        if not len(readings["angle_rad"]):
            return
        self._write(encode_encoder_chunk(readings))
        self.encoder_chunks.append({name: np.asarray(readings[name]) for name, _ in ENCODER_FIELDS})

    def encoder_readings(self) -> dict:
        """All encoder readings journaled, as one dict of arrays."""
        return concat_encoder(self.encoder_chunks)

    def close(self) -> None:
        if self._handle is not None and not self._handle.closed:
            self._handle.close()

    def __enter__(self) -> "Journal":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _fsync_dir(folder: Path) -> None:
    """Makes a new file's directory entry durable (POSIX); a no-op where unsupported."""
    try:
        fd = os.open(folder or ".", os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def open_journal(journal_path: str | os.PathLike, identity: dict, *, n_lines: int, n_beams: int,
                 started_unix_s: float, resume: bool) -> Journal:
    """A new journal, or (with ``resume``) the one at ``journal_path`` continued.

    A ``resume`` with no journal there starts a new one, with a warning.

    Raises:
      JournalError: see :meth:`Journal.create` and :meth:`Journal.resume`.
    """
    header = Journal.make_header(identity, n_lines=n_lines, n_beams=n_beams, started_unix_s=started_unix_s)
    journal_path = Path(journal_path)
    if resume and not journal_path.exists():
        log.warning("no journal at %s to resume; starting a new scan", journal_path)
        resume = False
    return Journal.resume(journal_path, header) if resume else Journal.create(journal_path, header)
