"""SCIP 2.0 pure functions against the specification's own examples, and round trips."""

import subprocess
import sys

import numpy as np
import pytest

from plantsim.hardware.urg import protocol as p
from plantsim.sensor.spec import BeamStatus


# The worked examples of the SCIP 2.0 specification (C-42-03320B, section 6, figures 2-7).
@pytest.mark.parametrize("value, n_chars, chars", [(1234, 2, "CB"), (5432, 3, "1Dh"), (16_000_000, 4, "m2@0")])
def test_spec_encoding_examples(value, n_chars, chars):
    assert p.encode(value, n_chars) == chars
    assert p.decode(chars) == value


# Lines of a URG-04LX's replies as printed in the vendor's examples (urgnetwork wiki,
# SCIP 2.0 specification 8.12): the character after ';' is the checksum of the part
# before it, and "00P"/"99b" are the status lines.
@pytest.mark.parametrize("line", ["DMIN:20;4", "DMAX:5600;_", "AMIN:44;7", "AMAX:725;o", "AFRT:384;6",
                                  "SCAN:600;e", "PROT:SCIP 2.0;N", "SERI:H0614967;V", "LASR:OFF;7",
                                  "MODL:URG-04LX(Hokuyo Automatic Co.,Ltd.);N"])
def test_vendor_key_value_checksums(line):
    assert p.check_line(line, semicolon_optional=True) == line[:-1]
    assert p.checksum(line[:-2]) == line[-1]


def test_status_checksums():
    assert p.checksum("00") == "P"
    assert p.checksum("99") == "b"
    assert p.check_line("00P") == "00"


def test_checksum_with_semicolon_summed_is_accepted_too():
    body = "DMIN:20;"
    assert p.check_line(body + p.checksum(body), semicolon_optional=True) == body


def test_bad_checksum_raises():
    with pytest.raises(p.ScipChecksumError, match="checksum mismatch"):
        p.check_line("00Q")


def test_encode_refuses_overflow_and_negatives():
    with pytest.raises(ValueError, match=r"\[0, 4095\]"):
        p.encode(4096, 2)
    with pytest.raises(ValueError, match="value must be"):
        p.encode(-1, 3)


def test_round_trip_random_values():
    rng = np.random.default_rng(3)
    for n_chars in (2, 3, 4):
        values = rng.integers(0, 1 << (6 * n_chars), size=200)
        chars = "".join(p.encode(int(v), n_chars) for v in values)
        assert p.encode_array(values, n_chars) == chars
        np.testing.assert_array_equal(p.decode_array(chars, n_chars), values)


def test_format_command_with_tag():
    assert p.format_command("GD", p.range_params(44, 725, 1), tag="a1") == b"GD0044072501;a1\n"
    assert p.format_command("MD", p.stream_params(44, 725, 1, 0, 0)) == b"MD0044072501000\n"
    with pytest.raises(ValueError, match="at most 16"):
        p.format_command("VV", tag="x" * 17)
    with pytest.raises(ValueError, match="at most 16"):
        p.format_command("VV", tag="bad;tag")
    with pytest.raises(ValueError, match="end_step must be >= start_step"):
        p.range_params(100, 50, 1)


def _gd_reply(values_mm, *, tag="t"):
    data = "".join(p.encode(v, 3) for v in values_mm)
    lines = ["GD0000%04d01;%s" % (len(values_mm) - 1, tag), "00P", p.encode(16_000_000, 4) + p.checksum("m2@0")]
    lines += p.data_lines(data)
    return ("\n".join(lines) + "\n\n").encode()


def test_parse_gd_reply_with_blocks_split_across_lines():
    values = list(range(20, 20 + 50 * 37, 37))  # 50 values x 3 chars = 150 chars: 3 lines, values split
    block = _gd_reply(values)
    lines = block.decode().split("\n")
    assert [len(line) for line in lines[3:6]] == [65, 65, 23]  # 64 + checksum, the rest
    [raw] = p.ReplyParser().feed(block)
    reply = p.parse_reply(raw)
    assert reply.command == "GD" and reply.tag == "t" and reply.status == "00"
    assert p.parse_timestamp(reply) == 16_000_000
    np.testing.assert_array_equal(p.parse_ranges_mm(reply), values)


def test_streaming_parser_accepts_any_chunking():
    stream = _gd_reply([100, 200, 300], tag="a") + b"\n" + _gd_reply([400] * 30, tag="b")
    for chunk in (1, 2, 7, 64, len(stream)):
        parser = p.ReplyParser()
        blocks = []
        for i in range(0, len(stream), chunk):
            blocks += parser.feed(stream[i:i + chunk])
        assert [p.parse_reply(b).tag for b in blocks] == ["a", "b"]
        assert parser.pending == 0


def test_corrupted_data_line_is_a_checksum_error():
    block = bytearray(_gd_reply([1000] * 30))
    block[-3] ^= 0x01  # a data character of the last line
    with pytest.raises(p.ScipChecksumError):
        p.parse_reply(bytes(block[:-1]))


def test_reply_without_status_is_a_framing_error():
    with pytest.raises(p.ScipFramingError, match="without a status"):
        p.parse_reply(b"GD0044072501\n")


def test_scip11_status_is_one_character():
    reply = p.parse_reply(b"QT\nE\n")
    assert reply.status == "E"


def test_key_values():
    reply = p.parse_reply(b"PP\n00P\nDMIN:20;4\nAFRT:384;6\n")
    assert p.parse_key_values(reply) == {"DMIN": "20", "AFRT": "384"}


def test_unwrap_timestamp_across_the_24_bit_wrap():
    m = p.TIMESTAMP_MODULUS_MS
    assert p.unwrap_timestamp_ms(50, m - 50) == m + 50
    assert p.unwrap_timestamp_ms(m - 50, m + 50) == m - 50
    assert p.unwrap_timestamp_ms(1000, 900) == 1000


def test_error_codes_map_to_beam_statuses():
    raw = np.array([0, 1, 2, 6, 7, 8, 9, 18, 19, 20, 1234, 5601])
    ranges_m, status = p.ranges_from_raw(raw, range_max_mm=5600)
    S = BeamStatus
    assert list(status) == [S.NO_ECHO, S.LOW_INTENSITY, S.LOW_INTENSITY, S.NO_ECHO, S.EDGE, S.EDGE, S.NO_ECHO,
                            S.NO_ECHO, S.NO_ECHO, S.OK, S.OK, S.NO_ECHO]
    assert np.isnan(ranges_m[:9]).all() and np.isnan(ranges_m[-1])
    assert ranges_m[9] == 0.020 and ranges_m[10] == 1.234
    assert set(range(20)) - set(p.URG04LX_ERROR_CODES) == {3, 4, 5}  # codes the table does not list


def test_raw_from_ranges_round_trip():
    S = BeamStatus
    ranges = np.array([1.2344, 0.010, np.nan, 5.0, 1.0, 1.0, 1.0])
    status = np.array([S.OK, S.OK, S.OK, S.OK, S.NO_ECHO, S.LOW_INTENSITY, S.EDGE])
    raw = p.raw_from_ranges(ranges, status)
    assert list(raw) == [1234, 6, 0, 5000, 0, 1, 7]
    back_m, back_status = p.ranges_from_raw(raw)
    assert back_m[0] == 1.234 and list(back_status[4:]) == [S.NO_ECHO, S.LOW_INTENSITY, S.EDGE]
    # GS/MS carry 12 bits: 5 m does not fit and is sent as 0.
    assert p.raw_from_ranges(ranges, status, n_chars=2)[3] == 0


def test_status_meanings():
    assert p.status_meaning("GD", "10") == "laser is off (send BM first)"
    assert p.status_meaning("MD", "06") == "scan interval is not numeric"
    assert p.status_meaning("TM", "04").startswith("time requested")
    assert p.status_meaning("VV", "0G").startswith("string after")
    assert p.status_meaning("GD", "55").startswith("hardware trouble")


def test_import_plantsim_loads_neither_serial_nor_the_urg_package():
    code = ("import sys, plantsim; bad = [m for m in ('serial', 'plantsim.hardware.urg') if m in sys.modules]; "
            "print(bad); sys.exit(1 if bad else 0)")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr
