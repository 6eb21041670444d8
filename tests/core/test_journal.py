"""The append-only journal DSM builds resume from: whole records survive, a torn tail is dropped."""

from __future__ import annotations

import threading

from citylod.core import journal


def test_records_from_many_threads_are_all_indexed(tmp_path) -> None:
    folder = tmp_path / "j"

    def writer(t: int) -> None:
        for k in range(50):
            journal.append(folder, f"t{t}/{k}", bytes([t]) * (k * 37))
        journal.close(folder)

    threads = [threading.Thread(target=writer, args=(t,)) for t in range(4)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    idx = journal.index(folder)
    assert len(list(folder.glob("*.log"))) == 4  # one file per writing thread
    assert len(idx) == 200
    assert idx["t3/49"].read() == bytes([3]) * (49 * 37)
    assert idx["t0/0"].read() == b""


def test_a_torn_record_and_what_follows_it_are_not_trusted(tmp_path) -> None:
    folder = tmp_path / "j"
    journal.append(folder, "a", b"first")
    journal.append(folder, "b", b"second" * 1000)
    journal.close(folder)
    (log,) = folder.glob("*.log")
    data = log.read_bytes()
    log.write_bytes(data[:-10])  # an interrupted write: the last record is cut short
    assert set(journal.index(folder)) == {"a"}
    flipped = bytearray(data)
    flipped[-3] ^= 0xFF  # a whole-length record with wrong bytes fails its checksum
    log.write_bytes(bytes(flipped))
    assert set(journal.index(folder)) == {"a"}
    # a resumed build appends to a new file, so its records are not hidden behind the torn tail
    journal.append(folder, "c", b"third")
    journal.close(folder)
    assert set(journal.index(folder)) == {"a", "c"}
    assert journal.index(tmp_path / "missing") == {}
