"""Names never become paths unchecked: a session id from a bag, a spill or a
``/session/end`` publisher is one safe directory name; products stay directly under their root;
``--overwrite`` replaces only a directory dpos wrote; a spill.json cannot make a reader open a file
outside its spill.  The graph's own checks are in test/dpos_ros/runtime/test_graph_trust.py."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from dpos_core.errors import OutputError, ProductsExistError
from dpos_ros.io import outdir
from dpos_ros.io import spill as S
from dpos_ros.io.outdir import PRODUCTS_MARKER, atomic_path, child_dir, is_products_dir, safe_name
from dpos_ros.io.session import RecordedSession
from dpos_ros.products.write import new_products_dir

# (raw session id, the directory name it becomes): the cases, then ours
NAMES = [
    ("../../x", "x"),
    ("/tmp/abs", "tmp_abs"),
    ("..", "session"),
    (".", "session"),
    ("", "session"),
    ("a/../../b", "a_.._.._b"),
    ("-rf", "rf"),
    (".hidden", "hidden"),
    ("with space 'and' \"quotes\"", "with_space_and_quotes_"),
    ("line\nbreak\x00nul", "line_break_nul"),
    ("C:\\windows\\x", "C_windows_x"),
    ("session_20261128_120000", "session_20261128_120000"),
    ("paper_su_seed1_2", "paper_su_seed1_2"),
    ("x" * 500, "x" * outdir.MAX_NAME_CHARS),
]


@pytest.mark.parametrize("raw, name", NAMES)
def test_a_session_id_becomes_one_safe_name(raw: str, name: str, tmp_path: Path) -> None:
    assert safe_name(raw) == name
    assert safe_name(name) == name  # idempotent: a safe name is kept as it is
    assert "/" not in name and "\\" not in name and name not in (".", "..") and not name.startswith((".", "-"))
    d = child_dir(tmp_path, name)
    assert d.resolve().parent == tmp_path.resolve()


@pytest.mark.parametrize("raw", ["../../x", "/etc", "..", "a/b"])
def test_recorded_session_sanitizes_its_id_and_says_so(raw: str) -> None:
    sess = RecordedSession(Path("rec"), raw, 0, np.zeros(3), None, {}, {}, {}, None)  # type: ignore[arg-type]
    assert sess.session_id == safe_name(raw)
    assert any(raw in w and "not a safe directory name" in w for w in sess.warnings)
    ok = RecordedSession(Path("rec"), "paper_su_seed1", 0, np.zeros(3), None, {}, {}, {}, None)  # type: ignore[arg-type]
    assert ok.session_id == "paper_su_seed1" and ok.warnings == []


def test_child_dir_refuses_unsafe_names_and_symlinks_out(tmp_path: Path) -> None:
    root = tmp_path / "out"
    root.mkdir()
    outside = tmp_path / "elsewhere"
    outside.mkdir()
    (root / "link").symlink_to(outside)
    for bad in ("../x", "/abs", "..", "a/b"):
        with pytest.raises(OutputError, match="not a safe directory name"):
            child_dir(root, bad)
    with pytest.raises(OutputError, match="resolves outside"):
        child_dir(root, "link")


def _foreign(tmp_path: Path) -> Path:
    d = tmp_path / "out" / "Documents"
    d.mkdir(parents=True)
    (d / "thesis.tex").write_text("precious")
    return d


@pytest.mark.parametrize("kind", ["unrelated", "symlink", "status_not_dpos", "file"])
def test_overwrite_replaces_only_what_dpos_wrote(tmp_path: Path, kind: str) -> None:
    """``--overwrite``: a directory without the marker (or a legacy status.json) is never replaced."""
    if kind == "unrelated":
        final = _foreign(tmp_path)
    elif kind == "symlink":
        target = _foreign(tmp_path)
        final = tmp_path / "out" / "sess"
        final.symlink_to(target)
    elif kind == "status_not_dpos":
        final = _foreign(tmp_path)
        (final / "status.json").write_text(json.dumps(["not", "ours"]))
    else:
        final = tmp_path / "out" / "sess"
        final.parent.mkdir(parents=True)
        final.write_text("a file")
    before = sorted(p.name for p in final.parent.iterdir())
    with pytest.raises(ProductsExistError, match="not a dpos products directory"):
        new_products_dir(final, overwrite=True)
    assert sorted(p.name for p in final.parent.iterdir()) == before
    if kind != "file":
        assert (final / "thesis.tex").read_text() == "precious"


def test_dpos_products_are_marked_and_replaceable(tmp_path: Path) -> None:
    final = tmp_path / "out" / "sess"
    assert new_products_dir(final, overwrite=False) == final
    assert (final / PRODUCTS_MARKER).is_file() and is_products_dir(final)
    tmp = new_products_dir(final, overwrite=True)
    assert tmp != final and (tmp / PRODUCTS_MARKER).is_file()
    legacy = tmp_path / "out" / "legacy"  # products of a version before the marker
    legacy.mkdir()
    (legacy / "status.json").write_text(json.dumps({"session_id": "legacy"}))
    assert is_products_dir(legacy)
    with pytest.raises(ProductsExistError, match="earlier run"):
        new_products_dir(final, overwrite=False)


def _spill(tmp_path: Path) -> Path:
    d = tmp_path / "spill"
    w = S.SpillWriter(d, "s1")
    w.write("/master/nav", "nav_msgs/msg/Odometry", 1, b"abcd")
    w.close()
    (tmp_path / "secret").write_text("root:x:0:0")
    return d


def _edit(d: Path, edit) -> None:
    meta = json.loads((d / "spill.json").read_text())
    edit(meta)
    (d / "spill.json").write_text(json.dumps(meta))


# spill.json edits: the (a file outside the spill, no topics, no file), then ours
SPILL_CASES = [
    ("parent", lambda m: m["topics"]["/master/nav"].update(file="../secret"), "not a file name in the spill"),
    ("absolute", lambda m: m["topics"]["/master/nav"].update(file="/etc/shadow"), "not a file name in the spill"),
    ("no topics", lambda m: m.pop("topics"), "'topics' is missing"),
    ("no file", lambda m: m["topics"]["/master/nav"].pop("file"), "needs a 'msgtype' and a 'file'"),
    ("file not a string", lambda m: m["topics"]["/master/nav"].update(file=3), "needs a 'msgtype' and a 'file'"),
    ("topics a list", lambda m: m.update(topics=["/master/nav"]), "'topics' is missing or not a mapping"),
    ("hidden", lambda m: m["topics"]["/master/nav"].update(file=".x"), "not a file name in the spill"),
    ("custom_data a list", lambda m: m.update(custom_data=[1]), "'custom_data' is not a mapping"),
]


@pytest.mark.parametrize("case, edit, match", SPILL_CASES, ids=[c[0] for c in SPILL_CASES])
def test_spill_json_cannot_point_outside_its_spill(tmp_path: Path, case: str, edit, match: str) -> None:
    d = _spill(tmp_path)
    _edit(d, edit)
    with pytest.raises(ValueError, match=match):
        S.spill_meta(d)
    with pytest.raises(ValueError, match=match):
        S.read_spill(d)


def test_spill_log_symlinked_out_of_the_spill_is_refused(tmp_path: Path) -> None:
    d = _spill(tmp_path)
    (d / "0.log").unlink()
    (d / "0.log").symlink_to(tmp_path / "secret")
    with pytest.raises(ValueError, match="resolves outside the spill"):
        S.spill_meta(d)


def test_a_good_spill_still_reads(tmp_path: Path) -> None:
    d = _spill(tmp_path)
    raw, _, sid, warnings = S.read_spill(d)
    assert sid == "s1" and raw["/master/nav"].times == [1] and warnings == []


def test_atomic_path_leaves_no_partial_file(tmp_path: Path) -> None:
    """A full disk while writing nav.csv (dpos-ifa) leaves neither nav.csv nor its temporary file."""
    target = tmp_path / "nav.csv"
    with pytest.raises(OSError, match="No space left") as e:
        with atomic_path(target) as tmp:
            tmp.write_text("half a fi")
            raise OSError(28, os.strerror(28))  # as np.savetxt raises it: no file name
    assert e.value.filename == str(target)
    assert list(tmp_path.iterdir()) == []
    with atomic_path(target) as tmp:
        tmp.write_text("whole\n")
    assert target.read_text() == "whole\n" and [p.name for p in tmp_path.iterdir()] == ["nav.csv"]


def test_dpos_process_keeps_a_session_id_out_of_the_path_and_overwrite_off_foreign_dirs(tmp_path: Path, capsys) -> None:
    """The issue's case end to end, up to the products: a recording whose session id is
    ``../../escaped`` and an unrelated ``OUT/escaped/``: ``--overwrite`` refuses it, nothing is
    written outside OUT and nothing is removed (the processing itself is not run: it is refused first)."""
    from repo_paths import REPO

    from dpos_ros.cli import process

    bag = tmp_path / "rec"
    bag.mkdir()
    sample = REPO / "bags" / "paper_su_pair_seed1_45s"
    for f in sample.iterdir():
        data = f.read_bytes()
        (bag / f.name).write_bytes(data.replace(b"dpos.session_id: paper_su_seed1", b"dpos.session_id: ../../escaped")
                                   if f.name == "metadata.yaml" else data)
    out = tmp_path / "a" / "b" / "out"
    (out / "escaped").mkdir(parents=True)
    (out / "escaped" / "thesis.tex").write_text("precious")
    assert process.main([str(bag), "--workers", "1", "--overwrite", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "'../../escaped' is not a safe directory name: using 'escaped'" in err
    assert "is not a dpos products directory" in err and "Traceback" not in err
    assert (out / "escaped" / "thesis.tex").read_text() == "precious"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a", "rec"] and sorted(p.name for p in out.iterdir()) == ["escaped"]
