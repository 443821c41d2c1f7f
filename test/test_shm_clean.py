"""The test session's clean-up of stale Fast DDS shared-memory files (test/shm_clean.py): a group
of files (segment or port, its lock files, its semaphore) goes only when nobody holds its lock,
no process has one of its files open and all of them are old enough."""

import fcntl
import os
import time

from shm_clean import group_of, remove_stale, stale_files


def _make(tmp_path, name, age_s=120.0):
    (tmp_path / name).write_bytes(b"x")
    t = time.time() - age_s
    os.utime(tmp_path / name, (t, t))


def test_groups_go_only_when_nobody_holds_them(tmp_path):
    assert group_of("sem.fastdds_port7413_mutex") == group_of("fastdds_port7413_el") == "fastdds_port7413"
    assert group_of("other") is None
    for name in ("fastdds_port7413", "fastdds_port7413_el", "sem.fastdds_port7413_mutex",  # stale
                 "fastdds_aaaa", "fastdds_aaaa_el",  # its owner holds the lock
                 "fastdds_bbbb", "fastdds_bbbb_el",  # a process has the segment open
                 "fastdds_cccc", "fastdds_cccc_el",  # one file too young
                 "fastdds_port9000", "other_file"):  # fmt: skip
        _make(tmp_path, name)
    _make(tmp_path, "fastdds_cccc_el", age_s=1.0)
    owner = os.open(tmp_path / "fastdds_aaaa_el", os.O_RDONLY)
    fcntl.flock(owner, fcntl.LOCK_EX)
    segment = open(tmp_path / "fastdds_bbbb", "rb")  # held open while checking
    try:
        stale = {p.name for p in stale_files(tmp_path, min_age_s=30.0)}
        assert stale == {"fastdds_port7413", "fastdds_port7413_el", "sem.fastdds_port7413_mutex", "fastdds_port9000"}
        assert remove_stale(tmp_path, min_age_s=30.0) == 4
    finally:
        os.close(owner)
        segment.close()
    left = sorted(p.name for p in tmp_path.iterdir())
    assert left == ["fastdds_aaaa", "fastdds_aaaa_el", "fastdds_bbbb", "fastdds_bbbb_el", "fastdds_cccc",
                    "fastdds_cccc_el", "other_file"]  # fmt: skip
    # released: the lock's and the open file's groups are stale now
    assert {p.name for p in stale_files(tmp_path, min_age_s=30.0)} == {
        "fastdds_aaaa", "fastdds_aaaa_el", "fastdds_bbbb", "fastdds_bbbb_el"}  # fmt: skip
