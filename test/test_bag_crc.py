"""Each byte of a bag is checksummed once: the data section's CRC over an uncompressed chunk's
records is combined from the chunk's own CRC (record/crc.py), and is still the CRC of every byte
of the data section (docs/recording.md, "CRCs")."""

from __future__ import annotations

import zlib

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from haptic_teleop.record import crc
from haptic_teleop.record.crc import COMBINE_FROM, combine


@settings(max_examples=300, deadline=None)
@given(a=st.binary(max_size=300), b=st.binary(max_size=300), pad=st.integers(0, 5_000_000))
def test_combine_is_the_crc_of_the_concatenation(a, b, pad):
    b = b + bytes(pad % 70_001 if pad % 3 else pad)  # lengths from 0 to 5 MB, every digit pattern
    assert combine(zlib.crc32(a), zlib.crc32(b), len(b)) == zlib.crc32(a + b)


def test_combine_refuses_a_length_it_cannot_shift_by():
    with pytest.raises(ValueError, match="got -1"):
        combine(0, 0, -1)
    with pytest.raises(ValueError, match="2\\^32 - 1"):
        crc.x_to_8n(1 << 32)


def test_a_bags_data_section_crc_is_one_pass_over_its_bytes(tmp_path, monkeypatch):
    """A bag of 1 MiB chunks (combined, as the engine writes them): mcap's validating stream reader
    checks every chunk's CRC and the data section's (DataEnd), and the writer combined rather than
    checksummed again (counted)."""
    from mcap.records import DataEnd
    from mcap.stream_reader import StreamReader

    from haptic_teleop.engine.lockstep import COLUMNS
    from haptic_teleop.record import mcap
    from haptic_teleop.record.recorder import RunRecorder

    used = []

    def counted(a: int, b: int, n: int) -> int:
        used.append(n)
        return combine(a, b, n)

    monkeypatch.setattr(mcap, "combine", counted)
    ticks = 4000
    rows = np.sin(np.arange(ticks * len(COLUMNS), dtype=np.float64).reshape(ticks, len(COLUMNS)))
    rec = RunRecorder(tmp_path / "bag", "scene: {}\n", 1_000_000, True, True, len(COLUMNS), parallel=False)
    for a in range(0, ticks, 1000):
        rec.append(rows[a : a + 1000])
    rec.close({"ticks": ticks})
    (path,) = (tmp_path / "bag").glob("*.mcap")
    assert used and min(used) >= COMBINE_FROM  # the big chunks' CRCs were combined
    with open(path, "rb") as f:
        ends = [r for r in StreamReader(f, validate_crcs=True).records if isinstance(r, DataEnd)]
    assert len(ends) == 1 and ends[0].data_section_crc != 0
    data = path.read_bytes()
    # the data section: from the file's start through the byte before DataEnd (op 0x0F, length 4, crc)
    end = data.rindex(b"\x0f\x04\x00\x00\x00\x00\x00\x00\x00" + ends[0].data_section_crc.to_bytes(4, "little"))
    assert zlib.crc32(data[:end]) == ends[0].data_section_crc


@settings(max_examples=200, deadline=None)
@given(data=st.binary(max_size=5000), start=st.integers(0, 2**32 - 1), cut=st.integers(0, 5000))
def test_the_recorders_crc32_is_zlibs(data, start, cut):
    """record/crc.py's `crc32` (ISA-L's when installed) gives zlib's values: from any start value,
    over bytes and over a numpy array's memory (what the writer hands it)."""
    assert crc.crc32(data, start) == zlib.crc32(data, start)
    view = np.frombuffer(data, dtype=np.uint8)[cut:].data
    assert crc.crc32(view, start) == zlib.crc32(bytes(view), start)


def test_a_bag_is_the_same_bytes_with_zlibs_crc32(tmp_path, monkeypatch):
    """The same calls with the standard library's CRC-32 in the writer give the same file: the fast
    implementation changes the speed only."""
    from haptic_teleop.engine.lockstep import COLUMNS
    from haptic_teleop.record import mcap
    from haptic_teleop.record.recorder import RunRecorder

    rows = np.random.default_rng(3).normal(size=(3000, len(COLUMNS)))

    def record(bag):
        rec = RunRecorder(bag, "scene: {}\n", 1_000_000, True, True, len(COLUMNS), parallel=False)
        rec.append(rows)
        return (rec.close({"ticks": 3000}) / "bag.mcap").read_bytes()

    fast = record(tmp_path / "a" / "bag")
    monkeypatch.setattr(mcap, "crc32", zlib.crc32)
    assert record(tmp_path / "b" / "bag") == fast
    assert crc.CRC_IMPLEMENTATION == "isal"  # the test extra installs it: the fast path is the one compared
