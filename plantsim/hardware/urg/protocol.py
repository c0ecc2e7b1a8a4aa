"""Hokuyo SCIP 2.0 as pure functions: encodings, checksums, commands, replies, ranges.

Sources (facts only, no code taken): Hokuyo "Communication Protocol Specification
for SCIP2.0", drawing C-42-03320B (2006-2008), referred to as [SCIP] with its
section; the urgnetwork wiki (sourceforge.net/p/urgnetwork/wiki/scip_status_en) for
the VV/PP/II replies of a URG-04LX; Hokuyo's ``urg_library`` (``urg_sensor.c``) for
behaviour the document leaves open (checksums of key:value lines, the SCIP 1.1 and
time-adjust answers to ``QT``).

* Every number is sent as 6-bit groups, most significant first, each as the
  character ``0x30 + group`` ([SCIP] 6: 2, 3 and 4 characters).
* The checksum of a line is the sum of its data bytes, lower 6 bits, plus 0x30
  ([SCIP] 7). On the URG-04LX's VV/PP/II lines (``KEY:value;c``) the ``;`` is not
  summed (the wiki's examples); later sensors sum it, so :func:`check_line` takes both
  (as ``urg_library`` does).
* A reply is the command's echo, a status line (2 characters + checksum), data lines
  of at most 64 characters + checksum, and an empty line: it ends with LF LF
  ([SCIP] 7). A range block may be split across two lines: the data characters of all
  lines are joined before decoding ([SCIP] 8.1).
"""

from __future__ import annotations

import dataclasses
import re

import numpy as np

from plantsim.sensor.spec import BeamStatus

LF = b"\n"
MAX_LINE_CHARS = 64  # data characters per line before the checksum ([SCIP] 8.1)
MAX_TAG_CHARS = 16  # the optional ";string" after a command ([SCIP] 7)
TIMESTAMP_MODULUS_MS = 1 << 24  # 24-bit millisecond timer ([SCIP] 8.1, "Time Stamp")
ERROR_CODE_LIMIT_MM = 20  # range values below this are error codes ([SCIP] 8.1, table 3)
_TAG_RE = re.compile(r"[A-Za-z0-9 ._+@]*")  # letters, digits, blank, . _ + @ ([SCIP] 7)


class ScipError(ValueError):
    """Bytes that are not a valid SCIP 2.0 reply."""


class ScipChecksumError(ScipError):
    """A line's checksum character does not match its data."""


class ScipFramingError(ScipError):
    """A reply whose lines are not where SCIP puts them (echo, status, data, LF LF)."""


# --- encodings ---------------------------------------------------------------------

def encode(value: int, n_chars: int) -> str:
    """``value`` as ``n_chars`` SCIP characters (6 bits each, most significant first).

    Raises:
        ValueError: ``value`` is negative or needs more than ``6 * n_chars`` bits
            (never truncated silently).
    """
    value = int(value)
    if not 0 <= value < 1 << (6 * n_chars):
        raise ValueError(f"value must be in [0, {(1 << 6 * n_chars) - 1}] for a {n_chars}-character "
                         f"encoding, got {value}")
    return "".join(chr(0x30 + ((value >> (6 * (n_chars - 1 - i))) & 0x3F)) for i in range(n_chars))


def encode_array(values: np.ndarray, n_chars: int) -> str:
    """Many values as one run of ``n_chars``-character groups (as :func:`encode`, vectorised).

    Raises:
        ValueError: a value is negative or does not fit in ``6 * n_chars`` bits.
    """
    values = np.asarray(values, dtype=np.int64)
    if values.size and (values.min() < 0 or values.max() >= 1 << (6 * n_chars)):
        raise ValueError(f"values must be in [0, {(1 << 6 * n_chars) - 1}] for a {n_chars}-character encoding")
    shifts = 6 * np.arange(n_chars - 1, -1, -1, dtype=np.int64)
    groups = ((values[:, None] >> shifts) & 0x3F) + 0x30
    return groups.astype(np.uint8).tobytes().decode("ascii")


def decode(chars: str) -> int:
    """The number encoded by SCIP characters (any count).

    Raises:
        ScipError: a character outside ``0x30 .. 0x6F``.
    """
    value = 0
    for c in chars:
        group = ord(c) - 0x30
        if not 0 <= group < 64:
            raise ScipError(f"character {c!r} is not a SCIP encoding character (0x30-0x6F)")
        value = (value << 6) | group
    return value


def decode_array(chars: str, n_chars: int) -> np.ndarray:
    """A run of ``n_chars``-character values. Returns (n,) int64.

    Raises:
        ScipError: the length is not a multiple of ``n_chars`` or a character is invalid.
    """
    if len(chars) % n_chars:
        raise ScipError(f"{len(chars)} data characters do not split into {n_chars}-character values")
    codes = np.frombuffer(chars.encode("latin-1"), dtype=np.uint8).astype(np.int64) - 0x30
    if codes.size and (codes.min() < 0 or codes.max() > 63):
        raise ScipError("range data holds a character outside 0x30-0x6F")
    groups = codes.reshape(-1, n_chars)
    weights = 1 << (6 * np.arange(n_chars - 1, -1, -1, dtype=np.int64))
    return groups @ weights


def checksum(data: str) -> str:
    """The checksum character of a line's data: (sum of bytes & 0x3F) + 0x30 ([SCIP] 7)."""
    return chr((sum(data.encode("latin-1")) & 0x3F) + 0x30)


def check_line(line: str, *, semicolon_optional: bool = False) -> str:
    """A data or status line's data, its checksum character verified.

    With ``semicolon_optional`` (VV/PP/II's ``KEY:value;c`` lines) the checksum may
    or may not sum the ``;``; range data lines, where ``;`` is a data character, must
    match exactly.

    Raises:
        ScipChecksumError: the checksum does not match.
        ScipFramingError: the line is empty.
    """
    if not line:
        raise ScipFramingError("an empty line where a data line with a checksum was expected")
    data, given = line[:-1], line[-1]
    if checksum(data) == given:
        return data
    if semicolon_optional and data.endswith(";") and checksum(data[:-1]) == given:
        return data
    raise ScipChecksumError(f"checksum mismatch in line {line!r}: expected {checksum(data)!r}")


def data_lines(data: str) -> list[str]:
    """``data`` split into lines of at most 64 characters, each with its checksum."""
    return [data[i:i + MAX_LINE_CHARS] + checksum(data[i:i + MAX_LINE_CHARS])
            for i in range(0, len(data), MAX_LINE_CHARS)]


# --- commands ---------------------------------------------------------------------

def check_tag(tag: str) -> None:
    """Raises ValueError unless ``tag`` is a valid SCIP string (<= 16 characters of
    letters, digits, blank and ``. _ + @``)."""
    if not isinstance(tag, str) or len(tag) > MAX_TAG_CHARS or not _TAG_RE.fullmatch(tag):
        raise ValueError(f"tag must be at most {MAX_TAG_CHARS} letters, digits, blanks or '._+@', got {tag!r}")


def format_command(command: str, params: str = "", tag: str | None = None) -> bytes:
    """A command line: symbol, parameters, optional ``;tag`` echoed back, LF.

    Example: ``format_command("GD", "0044072501", tag="a1") == b"GD0044072501;a1\\n"``.
    """
    if not command or not command.isascii() or "\n" in command + params:
        raise ValueError(f"command must be ASCII without a line feed, got {command!r}")
    line = command + params
    if tag is not None:
        check_tag(tag)
        line += ";" + tag
    return (line + "\n").encode("ascii")


def range_params(start_step: int, end_step: int, cluster: int) -> str:
    """GD/GS/MD/MS parameters: start (4 digits), end (4), cluster count (2)."""
    for name, value, digits in (("start_step", start_step, 4), ("end_step", end_step, 4),
                                ("cluster", cluster, 2)):
        if not (isinstance(value, (int, np.integer)) and 0 <= value < 10 ** digits):
            raise ValueError(f"{name} must be an integer in [0, {10 ** digits - 1}], got {value!r}")
    if end_step < start_step:
        raise ValueError(f"end_step must be >= start_step, got {start_step}..{end_step}")
    return f"{start_step:04d}{end_step:04d}{cluster:02d}"


def stream_params(start_step: int, end_step: int, cluster: int, skip: int, n_scans: int) -> str:
    """MD/MS parameters: the GD ones, scan interval (1 digit: scans skipped), count (2; 0 = until QT)."""
    if not (isinstance(skip, int) and 0 <= skip <= 9):
        raise ValueError(f"skip must be an integer in [0, 9], got {skip!r}")
    if not (isinstance(n_scans, int) and 0 <= n_scans <= 99):
        raise ValueError(f"n_scans must be an integer in [0, 99] (0: until QT), got {n_scans!r}")
    return range_params(start_step, end_step, cluster) + f"{skip:d}{n_scans:02d}"


# --- replies ----------------------------------------------------------------------

@dataclasses.dataclass(frozen=True)
class Reply:
    """One reply block, its checksums verified.

    Attributes:
        echo: the echoed command line (with its ``;tag``).
        status: the 2-character status ("00", "99", error codes), or SCIP 1.1's one
            character (e.g. "E", "0"), which has no checksum.
        lines: the data lines' data, checksum characters removed.
    """

    echo: str
    status: str
    lines: tuple[str, ...]

    @property
    def command(self) -> str:
        """The command's symbol: the echo's first two characters (or "SCIP2.0")."""
        body = self.echo.split(";", 1)[0]
        return body if body.startswith("SCIP") else body[:2]

    @property
    def params(self) -> str:
        body = self.echo.split(";", 1)[0]
        return "" if body.startswith("SCIP") else body[2:]

    @property
    def tag(self) -> str | None:
        return self.echo.split(";", 1)[1] if ";" in self.echo else None

    @property
    def data(self) -> str:
        """All data lines joined (range blocks split across lines become whole)."""
        return "".join(self.lines)


def parse_reply(block: bytes) -> Reply:
    """Parses one reply block (the bytes up to, not including, the final LF LF).

    Raises:
        ScipFramingError: no status line, non-ASCII bytes, or an over-long data line.
        ScipChecksumError: a status or data line's checksum does not match.
    """
    try:
        text = block.decode("ascii")
    except UnicodeDecodeError as exc:
        raise ScipFramingError(f"non-ASCII byte in a reply: {block[:40]!r}") from exc
    lines = text.rstrip("\n").split("\n")
    if len(lines) < 2:
        raise ScipFramingError(f"a reply without a status line: {block[:40]!r}")
    echo, status_line, rest = lines[0], lines[1], lines[2:]
    if len(status_line) == 1:  # SCIP 1.1: one status character, no checksum
        status = status_line
    elif len(status_line) == 3:
        status = check_line(status_line)
    else:
        raise ScipFramingError(f"status line {status_line!r} after {echo!r} is not 2 characters + checksum")
    key_values = echo[:2] in ("VV", "PP", "II")
    data = []
    for line in rest:
        if len(line) > MAX_LINE_CHARS + 1:
            raise ScipFramingError(f"data line of {len(line) - 1} characters (at most 64) after {echo!r}")
        data.append(check_line(line, semicolon_optional=key_values))
    return Reply(echo=echo, status=status, lines=tuple(data))


class ReplyParser:
    """Splits a byte stream, fed in arbitrary chunks, into reply blocks (ended by LF LF).

    Leading empty lines (a stray LF) are skipped. :meth:`feed` returns the complete
    blocks' bytes; :func:`parse_reply` checks them.
    """

    def __init__(self):
        self._buffer = bytearray()

    def feed(self, data: bytes) -> list[bytes]:
        self._buffer += data
        blocks = []
        while True:
            while self._buffer[:1] == LF:
                del self._buffer[:1]
            end = self._buffer.find(b"\n\n")
            if end < 0:
                return blocks
            blocks.append(bytes(self._buffer[:end + 1]))
            del self._buffer[:end + 2]

    @property
    def pending(self) -> int:
        """Bytes of an incomplete block held back."""
        return len(self._buffer)

    def clear(self) -> None:
        self._buffer.clear()


def parse_key_values(reply: Reply) -> dict[str, str]:
    """VV/PP/II lines ``KEY:value;`` as a dict (the trailing ``;`` removed).

    Raises:
        ScipFramingError: a line without ``KEY:``.
    """
    out = {}
    for line in reply.lines:
        key, sep, value = line.partition(":")
        if not sep or not key:
            raise ScipFramingError(f"{reply.command} line {line!r} is not KEY:value")
        out[key] = value[:-1] if value.endswith(";") else value
    return out


def key_value_lines(pairs: dict[str, str], *, semicolon_in_checksum: bool = False) -> list[str]:
    """``KEY:value;c`` lines; the URG-04LX leaves the ``;`` out of the checksum."""
    lines = []
    for key, value in pairs.items():
        body = f"{key}:{value}"
        lines.append(body + ";" + checksum(body + ";" if semicolon_in_checksum else body))
    return lines


def parse_timestamp(reply: Reply, line: int = 0) -> int:
    """The 4-character timestamp on data line ``line`` (GD/MD: 0; TM1: 0), ms mod 2^24.

    Raises:
        ScipFramingError: that line is missing or not 4 characters.
    """
    if len(reply.lines) <= line or len(reply.lines[line]) != 4:
        raise ScipFramingError(f"{reply.command} reply has no 4-character timestamp line")
    return decode(reply.lines[line])


def unwrap_timestamp_ms(raw_ms: int, reference_ms: int) -> int:
    """The unwrapped time nearest ``reference_ms`` whose value mod 2^24 is ``raw_ms``.

    The 24-bit timer wraps every 4.66 h; a stamp within +-2.33 h of the reference is
    placed unambiguously.
    """
    delta = (raw_ms - reference_ms) % TIMESTAMP_MODULUS_MS
    if delta >= TIMESTAMP_MODULUS_MS // 2:
        delta -= TIMESTAMP_MODULUS_MS
    return reference_ms + delta


def range_chars(command: str) -> int:
    """Characters per range value: 3 for GD/MD, 2 for GS/MS ([SCIP] 8.1)."""
    if command in ("GD", "MD"):
        return 3
    if command in ("GS", "MS"):
        return 2
    raise ValueError(f"command must be one of GD, GS, MD, MS, got {command!r}")


def parse_ranges_mm(reply: Reply) -> np.ndarray:
    """The raw range values of a GD/GS/MD/MS reply (after its timestamp line). Returns (n,) int64, mm or error codes."""
    return decode_array("".join(reply.lines[1:]), range_chars(reply.command))


# --- error codes and statuses -----------------------------------------------------

# [SCIP] 8.1, table 3 "ERROR CODES (URG-04LX, UBG-04LX-F01, UHG-08LX)": a range value
# below 20 is one of these, not a distance.
URG04LX_ERROR_CODES: dict[int, str] = {
    0: "detected object is possibly at 22 m (beyond the range)",
    1: "reflected light has low intensity",
    2: "reflected light has low intensity",
    6: "others",
    7: "distance data on the preceding and succeeding steps have errors",
    8: "intensity difference of two waves",
    9: "the same step had an error in the last two scans",
    **{code: "others" for code in range(10, 18)},
    18: "error reading due to a strong reflective object",
    19: "non-measurable step",
}

# How each code maps onto the sensor model's statuses. 1-2: too little light (the
# model's LOW_INTENSITY); 7: an edge (EDGE); 8: the two modulation waves disagree, as
# when a footprint straddles two surfaces (EDGE); 0 (an aliased far target) and every
# other code: no usable return (NO_ECHO). The URG-04LX has no "too near" code.
_CODE_STATUS = np.full(ERROR_CODE_LIMIT_MM, BeamStatus.NO_ECHO, dtype=np.int8)
_CODE_STATUS[[1, 2]] = BeamStatus.LOW_INTENSITY
_CODE_STATUS[[7, 8]] = BeamStatus.EDGE

# What the emulator sends for each status (the inverse, one code per status).
STATUS_CODE: dict[int, int] = {
    BeamStatus.NO_ECHO: 0,
    BeamStatus.LOW_INTENSITY: 1,
    BeamStatus.EDGE: 7,
    BeamStatus.TOO_NEAR: 6,  # no such code on the URG-04LX: "others" (read back as NO_ECHO)
}


def ranges_from_raw(raw_mm: np.ndarray, *, range_max_mm: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Raw values to metres and statuses.

    Args:
        raw_mm: (n,) int, mm or error codes (< 20).
        range_max_mm: DMAX; values beyond it are NO_ECHO. None: no limit.

    Returns:
        ranges_m: (n,) float64, metres, NaN where there is no range.
        status: (n,) int8 :class:`~plantsim.sensor.spec.BeamStatus` values.
    """
    raw_mm = np.asarray(raw_mm, dtype=np.int64)
    error = raw_mm < ERROR_CODE_LIMIT_MM
    status = np.where(error, _CODE_STATUS[np.clip(raw_mm, 0, ERROR_CODE_LIMIT_MM - 1)],
                      BeamStatus.OK).astype(np.int8)
    if range_max_mm is not None:
        status[~error & (raw_mm > range_max_mm)] = BeamStatus.NO_ECHO
    ranges_m = np.where(status == BeamStatus.OK, raw_mm / 1000.0, np.nan)
    return ranges_m, status


def raw_from_ranges(ranges_m: np.ndarray, status: np.ndarray, *, n_chars: int = 3) -> np.ndarray:
    """Metres and statuses to the raw values a URG-04LX sends (the emulator's side).

    A range is rounded to 1 mm; OK beams nearer than 20 mm or not finite become error
    codes; 2-character encodings (GS/MS) send 0 for ranges above 4095 mm.
    Returns (n,) int64.
    """
    ranges_m = np.asarray(ranges_m, dtype=np.float64)
    status = np.asarray(status)
    raw = np.zeros(ranges_m.shape, dtype=np.int64)
    for beam_status, code in STATUS_CODE.items():
        raw[status == beam_status] = code
    ok = (status == BeamStatus.OK) & np.isfinite(ranges_m)
    raw[ok] = np.round(ranges_m[ok] * 1000.0).astype(np.int64)
    raw[(status == BeamStatus.OK) & ~np.isfinite(ranges_m)] = STATUS_CODE[BeamStatus.NO_ECHO]
    raw[ok & (raw < ERROR_CODE_LIMIT_MM)] = STATUS_CODE[BeamStatus.TOO_NEAR]
    raw[raw >= 1 << (6 * n_chars)] = 0
    return raw


# --- status tables ([SCIP] 8 and 9) ------------------------------------------------

COMMON_STATUS: dict[str, str] = {
    "0A": "unable to create transmission data or reply internally",
    "0B": "buffer shortage, or a command repeated that is already being processed",
    "0C": "command with insufficient parameters",
    "0D": "undefined command",
    "0E": "undefined command (or not allowed now, e.g. in time-adjust mode)",
    "0F": "command with insufficient parameters",
    "0G": "string after ';' longer than 16 characters",
    "0H": "string after ';' has invalid characters",
    "0I": "sensor is in firmware update mode",
}

_RANGE_STATUS = {
    "01": "starting step is not numeric", "02": "end step is not numeric",
    "03": "cluster count is not numeric", "04": "end step is out of range",
    "05": "end step is smaller than starting step",
}

STATUS_TABLES: dict[str, dict[str, str]] = {
    "GD": {**_RANGE_STATUS, "10": "laser is off (send BM first)"},
    "MD": {**_RANGE_STATUS, "06": "scan interval is not numeric", "07": "number of scans is not numeric",
           "98": "resumed after confirming normal laser operation"},
    "BM": {"01": "unable to control the laser: laser malfunction", "02": "laser is already on"},
    "TM": {"01": "invalid control code", "02": "time-adjust mode is already on",
           "03": "time-adjust mode is already off", "04": "time requested while time-adjust mode is off"},
}
STATUS_TABLES["GS"] = STATUS_TABLES["GD"]
STATUS_TABLES["MS"] = STATUS_TABLES["MD"]

# Statuses that mean success: "00" everywhere, "99" for each streamed scan, and the
# "already so" answers, which leave the sensor where the command wanted it.
SUCCESS_STATUS: dict[str, tuple[str, ...]] = {
    "BM": ("00", "02"), "MD": ("00", "99"), "MS": ("00", "99"),
}


def status_meaning(command: str, status: str) -> str:
    """What a status means for ``command`` (the per-command table, then the common one)."""
    if status in ("00", "99"):
        return "ok"
    table = STATUS_TABLES.get(command[:2], {})
    if status in table:
        return table[status]
    if status in COMMON_STATUS:
        return COMMON_STATUS[status]
    if status.isdigit() and 21 <= int(status) <= 49:
        return "processing stopped to verify an error"
    if status.isdigit() and 50 <= int(status) <= 98:
        return "hardware trouble (laser or motor malfunction)"
    return "unknown status"
