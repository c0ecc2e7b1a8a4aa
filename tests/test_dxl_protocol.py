"""Tests of the Protocol 2.0 codec against the e-Manual and the SDK."""

import pytest
from dynamixel_sdk import Protocol2PacketHandler

from plantsim.hardware.dynamixel import protocol

PING_ID1 = bytes.fromhex("FF FF FD 00 01 03 00 01 19 4E")


def test_crc_check_value():
    assert protocol.crc16(b"123456789") == 0xFEE8


def test_crc_matches_sdk_table():
    data = bytes(range(256)) * 2
    assert protocol.crc16(data) == Protocol2PacketHandler().updateCRC(0, list(data), len(data))


def test_worked_ping_example():
    assert protocol.build_instruction(1, protocol.Instruction.PING) == PING_ID1
    packet = protocol.parse_packet(PING_ID1)
    assert (packet.dxl_id, packet.instruction, packet.params, packet.crc_ok) == (1, 1, b"", True)


def test_stuffing_round_trip_and_length():
    body = bytes([0x03, 0xFF, 0xFF, 0xFD, 0x01, 0xFF, 0xFF, 0xFD, 0xFD])
    stuffed = protocol.stuff(body)
    assert stuffed == bytes([0x03, 0xFF, 0xFF, 0xFD, 0xFD, 0x01, 0xFF, 0xFF, 0xFD, 0xFD, 0xFD])
    assert protocol.unstuff(stuffed) == body
    packet = protocol.build_instruction(7, protocol.Instruction.WRITE, body[1:])
    assert packet[5] | (packet[6] << 8) == len(stuffed) + 2
    decoded = protocol.parse_packet(packet)
    assert decoded.params == body[1:] and decoded.crc_ok


def test_stuffing_matches_sdk():
    params = [0x74, 0x00, 0xFF, 0xFF, 0xFD, 0x00]
    tx = [0] * 7 + [protocol.Instruction.WRITE] + params + [0, 0]
    tx[4], tx[5], tx[6] = 1, len(params) + 3, 0
    sdk = Protocol2PacketHandler().addStuffing(tx)
    ours = protocol.build_instruction(1, protocol.Instruction.WRITE, bytes(params))
    assert bytes(sdk[4:-2]) == ours[4:-2]


def test_status_packet_round_trip():
    status = protocol.build_status(3, 0x80 | protocol.ErrorCode.ACCESS, b"\x01\x02")
    packet = protocol.parse_packet(status)
    assert packet.is_status and packet.error == 0x87 and packet.params == b"\x01\x02"
    assert "hardware alert" in protocol.describe_error(packet.error)
    assert "EEPROM while torque is on" in protocol.describe_error(packet.error)


def test_streaming_parser_resyncs_on_garbage_and_split_reads():
    parser = protocol.PacketParser()
    corrupt = bytearray(protocol.build_status(1, 0, b"\x10"))
    corrupt[-1] ^= 0xFF
    stream = b"\x00\xff\x12" + PING_ID1 + b"\xff\xff\xfd\x00\x01\xff\xff" + bytes(corrupt) + PING_ID1
    packets = []
    for i in range(0, len(stream), 3):
        packets += parser.feed(stream[i : i + 3])
    assert [p.instruction for p in packets] == [1, 0x55, 1]
    assert [p.crc_ok for p in packets] == [True, False, True]
    assert parser.pending == 0


def test_parse_packet_refuses_partial():
    with pytest.raises(ValueError, match="exactly one"):
        protocol.parse_packet(PING_ID1[:-1])
