"""Dynamixel Protocol 2.0 codec: CRC, byte stuffing, packets, a streaming parser.

Source: ROBOTIS e-Manual, "DYNAMIXEL Protocol 2.0"
(https://emanual.robotis.com/docs/en/dxl/protocol2/).

Packet layout (LEN counts the stuffed bytes after it, CRC included)::

    instruction: FF FF FD 00 | ID | LEN_L LEN_H | INST | params... | CRC_L CRC_H
    status:      FF FF FD 00 | ID | LEN_L LEN_H | 0x55 | ERR | params... | CRC_L CRC_H

Everything here works on ``bytes`` and never touches a port.
"""

from __future__ import annotations

import dataclasses
import enum
import logging

_log = logging.getLogger(__name__)

HEADER = b"\xff\xff\xfd\x00"
BROADCAST_ID = 0xFE
MAX_ID = 0xFC
STATUS_INSTRUCTION = 0x55
MAX_PACKET_LENGTH = 1024  # the SDK's RXPACKET_MAX_LEN; longer LEN fields are garbage


class Instruction(enum.IntEnum):
    PING = 0x01
    READ = 0x02
    WRITE = 0x03
    REG_WRITE = 0x04
    ACTION = 0x05
    FACTORY_RESET = 0x06
    REBOOT = 0x08
    CLEAR = 0x10
    STATUS = 0x55
    SYNC_READ = 0x82
    SYNC_WRITE = 0x83
    FAST_SYNC_READ = 0x8A
    BULK_READ = 0x92
    BULK_WRITE = 0x93
    FAST_BULK_READ = 0x9A


class ErrorCode(enum.IntEnum):
    """Low 7 bits of a status packet's error byte."""

    NONE = 0
    RESULT_FAIL = 1
    INSTRUCTION = 2
    CRC = 3
    DATA_RANGE = 4
    DATA_LENGTH = 5
    DATA_LIMIT = 6
    ACCESS = 7


ERROR_ALERT_BIT = 0x80  # set in every status while Hardware Error Status != 0

ERROR_MESSAGES = {
    ErrorCode.RESULT_FAIL: "failed to process the instruction",
    ErrorCode.INSTRUCTION: "undefined or incorrect instruction",
    ErrorCode.CRC: "CRC of the instruction packet does not match",
    ErrorCode.DATA_RANGE: "data value out of range",
    ErrorCode.DATA_LENGTH: "data length does not match the register",
    ErrorCode.DATA_LIMIT: "data value exceeds its limit",
    ErrorCode.ACCESS: "address not accessible (read-only, undefined, or EEPROM while torque is on)",
}


def _crc_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x8005) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return tuple(table)


_CRC_TABLE = _crc_table()


def crc16(data: bytes, crc: int = 0) -> int:
    """CRC-16/BUYPASS (poly 0x8005, init 0, no reflection), as the e-Manual specifies."""
    for byte in data:
        crc = ((crc << 8) ^ _CRC_TABLE[((crc >> 8) ^ byte) & 0xFF]) & 0xFFFF
    return crc


def stuff(body: bytes) -> bytes:
    """Inserts 0xFD after every FF FF FD in ``body`` (instruction/status and params)."""
    out = bytearray()
    for byte in body:
        out.append(byte)
        if byte == 0xFD and len(out) >= 3 and out[-3] == 0xFF and out[-2] == 0xFF:
            out.append(0xFD)
    return bytes(out)


def unstuff(body: bytes) -> bytes:
    """Removes the 0xFD that :func:`stuff` inserted after each FF FF FD."""
    out = bytearray()
    i = 0
    while i < len(body):
        out.append(body[i])
        if body[i] == 0xFD and len(out) >= 3 and out[-3] == 0xFF and out[-2] == 0xFF:
            if i + 1 < len(body) and body[i + 1] == 0xFD:
                i += 1  # skip the stuffing byte
        i += 1
    return bytes(out)


def _frame(dxl_id: int, body: bytes) -> bytes:
    if not 0 <= dxl_id <= 0xFE:
        raise ValueError(f"dxl_id must be in [0, 254], got {dxl_id}")
    # Stuffing looks back across the header boundary only through the body itself:
    # the SDK stuffs instruction+params alone, and so do we.
    stuffed = stuff(body)
    length = len(stuffed) + 2
    packet = HEADER + bytes([dxl_id, length & 0xFF, length >> 8]) + stuffed
    crc = crc16(packet)
    return packet + bytes([crc & 0xFF, crc >> 8])


def build_instruction(dxl_id: int, instruction: int, params: bytes = b"") -> bytes:
    """Builds an instruction packet (stuffed, with CRC)."""
    return _frame(dxl_id, bytes([instruction]) + bytes(params))


def build_status(dxl_id: int, error: int = 0, params: bytes = b"") -> bytes:
    """Builds a status packet (stuffed, with CRC)."""
    if not 0 <= error <= 0xFF:
        raise ValueError(f"error must be a byte, got {error}")
    return _frame(dxl_id, bytes([STATUS_INSTRUCTION, error]) + bytes(params))


@dataclasses.dataclass(frozen=True)
class Packet:
    """A decoded packet.

    Attributes:
        dxl_id: servo ID, or 254 for broadcast.
        instruction: instruction byte (0x55 for a status packet).
        params: unstuffed parameters (for a status packet, after the error byte).
        error: status error byte; None for instruction packets.
        crc_ok: False when the received CRC did not match (the packet is still
            reported so that a servo can answer with a CRC error).
    """

    dxl_id: int
    instruction: int
    params: bytes
    error: int | None = None
    crc_ok: bool = True

    @property
    def is_status(self) -> bool:
        return self.instruction == STATUS_INSTRUCTION


def parse_packet(packet: bytes) -> Packet:
    """Decodes one complete packet.

    Raises:
        ValueError: if ``packet`` is not a whole, well-formed packet.
    """
    packets, rest = PacketParser.split(bytes(packet))
    if len(packets) != 1 or rest:
        raise ValueError(f"packet must hold exactly one Protocol 2.0 packet, got {bytes(packet).hex(' ')}")
    return packets[0]


class PacketParser:
    """Streaming parser: feed bytes as they arrive, get whole packets out.

    Garbage before a header is dropped, and so is a header whose length field is
    implausible, so the parser resyncs on the next FF FF FD 00.
    """

    def __init__(self):
        self._buffer = bytearray()

    def feed(self, data: bytes) -> list[Packet]:
        self._buffer += data
        packets, rest = self.split(bytes(self._buffer))
        self._buffer = bytearray(rest)
        return packets

    def clear(self) -> None:
        self._buffer.clear()

    @property
    def pending(self) -> int:
        """Bytes held back waiting for the rest of a packet."""
        return len(self._buffer)

    @staticmethod
    def split(buffer: bytes) -> tuple[list[Packet], bytes]:
        """Splits ``buffer`` into whole packets and the unconsumed tail."""
        packets = []
        start = 0
        while True:
            index = buffer.find(HEADER, start)
            if index < 0:
                # Keep a possible partial header at the end.
                keep = 0
                for n in (3, 2, 1):
                    if buffer[len(buffer) - n :] == HEADER[:n]:
                        keep = n
                        break
                if len(buffer) - keep > start:
                    _log.debug("dropped %d garbage bytes", len(buffer) - keep - start)
                return packets, buffer[len(buffer) - keep :]
            if index > start:
                _log.debug("dropped %d garbage bytes", index - start)
            if len(buffer) < index + 7:
                return packets, buffer[index:]
            length = buffer[index + 5] | (buffer[index + 6] << 8)
            if length < 3 or length > MAX_PACKET_LENGTH:
                start = index + 1  # not a real header: resync
                continue
            end = index + 7 + length
            if len(buffer) < end:
                return packets, buffer[index:]
            raw = buffer[index:end]
            crc_ok = crc16(raw[:-2]) == (raw[-2] | (raw[-1] << 8))
            body = unstuff(raw[7:-2])
            instruction = body[0]
            if instruction == STATUS_INSTRUCTION:
                if len(body) < 2:
                    start = index + 1
                    continue
                packet = Packet(raw[4], instruction, body[2:], error=body[1], crc_ok=crc_ok)
            else:
                packet = Packet(raw[4], instruction, body[1:], crc_ok=crc_ok)
            packets.append(packet)
            start = end


def describe_error(error: int) -> str:
    """Human-readable text for a status error byte ("" when 0)."""
    parts = []
    if error & ERROR_ALERT_BIT:
        parts.append("hardware alert (read Hardware Error Status)")
    code = error & 0x7F
    if code:
        try:
            parts.append(ERROR_MESSAGES[ErrorCode(code)])
        except ValueError:
            parts.append(f"unknown error code {code}")
    return "; ".join(parts)


# --- timing ---------------------------------------------------------------------------

#: Bits a byte takes on the bus: start bit, 8 data bits, stop bit (8N1).
BITS_PER_BYTE = 10
#: The USB serial adapter's latency timer (FTDI default 16 ms; the U2D2's too): a
#: short status can sit in the adapter this long before the host sees it. The SDK
#: allows two of them, plus 2 ms (``PortHandler.setPacketTimeout``).
USB_LATENCY_TIMER_S = 0.016
_SDK_EXTRA_S = 0.002


def bus_time_s(n_bytes: int, baud_bps: int) -> float:
    """Time ``n_bytes`` take on the wire at ``baud_bps`` (8N1), s."""
    if n_bytes < 0 or baud_bps <= 0:
        raise ValueError(f"n_bytes must be >= 0 and baud_bps > 0, got {n_bytes}, {baud_bps}")
    return n_bytes * BITS_PER_BYTE / baud_bps


def status_timeout_s(baud_bps: int, *, instruction_bytes: int, status_bytes: int, return_delay_s: float = 0.0,
                     allowance_s: float = 0.0) -> float:
    """How long a host should wait for a status packet, s: a margin derived from the protocol.

    The instruction and the status on the wire at ``baud_bps``, the servo's Return
    Delay Time between them, two USB latency periods and the SDK's 2 ms, plus
    ``allowance_s`` for the host's scheduler (a busy machine, or an emulator thread
    that shares its cores). A status later than this is late: the driver discards it
    by resynchronising and retries the request.

    Args:
        baud_bps: the bus's baud rate.
        instruction_bytes: length of the instruction packet, bytes.
        status_bytes: length of the expected status packet, bytes.
        return_delay_s: the servo's Return Delay Time (register 9, 2 us units), s.
        allowance_s: scheduler allowance, s.
    """
    if return_delay_s < 0 or allowance_s < 0:
        raise ValueError(f"return_delay_s and allowance_s must be >= 0, got {return_delay_s}, {allowance_s}")
    return (bus_time_s(instruction_bytes + status_bytes, baud_bps) + return_delay_s
            + 2 * USB_LATENCY_TIMER_S + _SDK_EXTRA_S + allowance_s)
