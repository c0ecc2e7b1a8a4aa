"""The append-only scan journal: round trip, torn tail, damage, identity checks."""

import json
import logging

import numpy as np
import pytest

from plantsim.errors import JournalError
from plantsim.scan.journal import Journal, JournalLine, encode_frame, read_journal

N_BEAMS = 7


def make_line(index: int, rng: np.random.Generator) -> JournalLine:
    range_m = rng.uniform(0.1, 2.0, N_BEAMS)
    range_m[rng.integers(N_BEAMS)] = np.nan
    return JournalLine(index=index, commanded_angle_rad=0.1 * index, reported_angle_rad=0.1 * index + 1e-4,
                       cast_angle_rad=0.1 * index + 1e-4, stamp_ns=500_000_000 * index, range_m=range_m,
                       status=rng.integers(0, 3, N_BEAMS).astype(np.uint8),
                       hit_class=rng.integers(0, 4, N_BEAMS).astype(np.uint8),
                       geom_id=rng.integers(-1, 9, N_BEAMS).astype(np.int32),
                       intensity=rng.uniform(0, 1, N_BEAMS).astype(np.float32) if index % 2 else None)


def header(identity=None, n_lines=5):
    identity = identity or {"scan": {"step_deg": 10.0}, "turntable": {"kind": "simulated"}}
    return Journal.make_header(identity, n_lines=n_lines, n_beams=N_BEAMS, started_unix_s=1.0e9)


def write_lines(path, count, rng, head=None):
    lines = [make_line(i, rng) for i in range(count)]
    with Journal.create(path, head or header()) as journal:
        for line in lines:
            journal.append(line)
    return lines


def assert_same_lines(a, b):
    assert len(a) == len(b)
    for x, y in zip(a, b):
        assert (x.index, x.commanded_angle_rad, x.reported_angle_rad, x.cast_angle_rad, x.stamp_ns) == (
            y.index, y.commanded_angle_rad, y.reported_angle_rad, y.cast_angle_rad, y.stamp_ns)
        assert (x.intensity is None) == (y.intensity is None)
        if x.intensity is not None:
            np.testing.assert_array_equal(x.intensity, y.intensity)
        np.testing.assert_array_equal(x.range_m, y.range_m)
        for name in ("status", "hit_class", "geom_id"):
            np.testing.assert_array_equal(getattr(x, name), getattr(y, name))
            assert getattr(x, name).dtype == getattr(y, name).dtype


def test_round_trip(tmp_path):
    rng = np.random.default_rng(0)
    lines = write_lines(tmp_path / "j", 3, rng)
    contents = read_journal(tmp_path / "j")
    assert contents.header == header() and contents.torn_bytes == 0
    assert_same_lines(contents.lines, lines)


@pytest.mark.parametrize("tail", ["cut", "zeros", "bad_crc"])
def test_torn_last_record_is_dropped_and_resume_overwrites_it(tmp_path, caplog, tail):
    rng = np.random.default_rng(1)
    path = tmp_path / "j"
    lines = write_lines(path, 3, rng)
    data = path.read_bytes()
    if tail == "cut":  # the crash hit in the middle of the last write
        path.write_bytes(data[:-5])
    elif tail == "zeros":  # the file grew but the data never landed
        path.write_bytes(data + b"\0" * 40)
    else:  # the last record's bytes are wrong
        path.write_bytes(data[:-1] + bytes([data[-1] ^ 0xFF]))
    with caplog.at_level(logging.WARNING):
        contents = read_journal(path)
    assert "dropped a torn last record" in caplog.text
    kept = 3 if tail == "zeros" else 2
    assert_same_lines(contents.lines, lines[:kept])
    with Journal.resume(path, header()) as journal:
        assert len(journal.lines) == journal.lines_resumed == kept
        for index in range(kept, 5):
            journal.append(make_line(index, np.random.default_rng(index)))
    contents = read_journal(path)
    assert contents.torn_bytes == 0 and [line.index for line in contents.lines] == [0, 1, 2, 3, 4]


def test_damage_before_valid_records_is_refused(tmp_path):
    path = tmp_path / "j"
    write_lines(path, 3, np.random.default_rng(2))
    data = bytearray(path.read_bytes())
    header_frame = len(encode_frame(json.dumps(header(), sort_keys=True).encode("utf-8")))
    data[header_frame + 20] ^= 0xFF  # inside line 0's record; lines 1 and 2 are intact
    path.write_bytes(bytes(data))
    with pytest.raises(JournalError, match=r"is damaged: a bad record at byte \d+ is followed by valid ones"):
        read_journal(path)


def test_journal_of_another_configuration_is_refused(tmp_path):
    path = tmp_path / "j"
    write_lines(path, 2, np.random.default_rng(3))
    other = header({"scan": {"step_deg": 5.0}, "turntable": {"kind": "simulated"}})
    with pytest.raises(JournalError, match=r"written for another configuration \(differs in: scan.step_deg\)"):
        Journal.resume(path, other)


def test_existing_journal_is_not_overwritten(tmp_path):
    path = tmp_path / "j"
    write_lines(path, 1, np.random.default_rng(4))
    with pytest.raises(JournalError, match="unfinished scan exists .* pass --resume"):
        Journal.create(path, header())
    assert len(read_journal(path).lines) == 1


def test_lines_must_come_in_order_once(tmp_path):
    rng = np.random.default_rng(5)
    with Journal.create(tmp_path / "j", header()) as journal:
        journal.append(make_line(0, rng))
        with pytest.raises(ValueError, match="line.index must be the next line, 1, got 0"):
            journal.append(make_line(0, rng))
        with pytest.raises(ValueError, match="line.index must be the next line, 1, got 2"):
            journal.append(make_line(2, rng))


def test_other_files_are_not_taken_for_journals(tmp_path):
    path = tmp_path / "scan.las.journal"
    path.write_bytes(b"LASF and so on")
    with pytest.raises(JournalError, match="is not a plantsim scan journal"):
        read_journal(path)


def test_torn_header_starts_over(tmp_path):
    path = tmp_path / "j"
    path.write_bytes(encode_frame(b'{"plantsim_journal": 1}')[:9])
    with Journal.resume(path, header()) as journal:
        assert journal.lines == []
    assert read_journal(path).header == header()
