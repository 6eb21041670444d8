"""Atomic writes and folder publishing: nothing half-written, never a user's folder deleted."""

from __future__ import annotations

import pytest

from citylod.core.errors import InputError
from citylod.core.fileio import atomic_write, atomic_write_text, publish_dir


def test_failed_write_leaves_nothing(tmp_path) -> None:
    def broken(tmp):
        tmp.write_text("half")
        raise RuntimeError("disk full")

    with pytest.raises(RuntimeError):
        atomic_write(tmp_path / "out.txt", broken)
    assert list(tmp_path.iterdir()) == []
    atomic_write_text(tmp_path / "sub" / "ok.txt", "done")
    assert (tmp_path / "sub" / "ok.txt").read_text() == "done"
    assert [p.name for p in (tmp_path / "sub").iterdir()] == ["ok.txt"]


def test_publish_replaces_an_earlier_output_but_not_a_foreign_folder(tmp_path) -> None:
    out = tmp_path / "out"
    for generation in ("a", "b"):
        part = tmp_path / "out.partial"
        part.mkdir()
        (part / "tileset.json").write_text(generation)
        publish_dir(part, out)
        assert (out / "tileset.json").read_text() == generation and not part.exists()
    docs = tmp_path / "Documents"
    docs.mkdir()
    (docs / "thesis.tex").write_text("precious")
    part = tmp_path / "p2"
    part.mkdir()
    with pytest.raises(InputError, match="Documents"):
        publish_dir(part, docs)
    assert (docs / "thesis.tex").read_text() == "precious" and part.exists()


def test_publishing_drops_the_temporaries_of_killed_writers(tmp_path) -> None:
    """A writer killed between writing and renaming leaves ``.name.tmpPID``; the resumed build rewrites the
    file, and publishing removes the stray temporary, nothing else."""
    from citylod.core.fileio import atomic_write_bytes, publish_dir

    partial = tmp_path / "out.partial"
    atomic_write_bytes(partial / "tiles" / "2" / "3-0-2.glb", b"glb")
    (partial / "tileset.json").write_text("{}")
    (partial / "tiles" / "2" / ".3-0-2.glb.tmp15389").write_bytes(b"half")  # as a SIGKILL leaves it
    (partial / "tiles" / ".a.npz.tmp77.npz").write_bytes(b"half")  # with the writer's suffix
    keep = [partial / ".hidden", partial / "tiles" / "x.tmp5", partial / "tiles" / ".b.tmpl"]
    for k in keep:
        k.write_bytes(b"user")
    publish_dir(partial, tmp_path / "out")
    got = sorted(str(f.relative_to(tmp_path / "out")) for f in (tmp_path / "out").rglob("*") if f.is_file())
    assert got == sorted([".hidden", "tileset.json", "tiles/.b.tmpl", "tiles/2/3-0-2.glb", "tiles/x.tmp5"])
