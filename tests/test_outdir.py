"""The output-directory policy: never touch a non-empty directory without force; with force remove
only what dualid wrote; a failed write leaves the directory as it was."""

import json

import pytest

from dualid.errors import OutputError
from dualid.report.outdir import MANIFEST, check_output_files, output_dir, write_output


def _write(files):
    def write(d):
        out = {}
        for name, text in files.items():
            (d / name).parent.mkdir(parents=True, exist_ok=True)
            (d / name).write_text(text)
            out[name] = d / name
        return out

    return write


def test_new_directory_gets_files_and_manifest(tmp_path):
    out = tmp_path / "a" / "out"
    paths = write_output(out, False, _write({"r.json": "1", "fig/x.png": "2"}))
    assert paths == {"r.json": out / "r.json", "fig/x.png": out / "fig/x.png"}
    assert (out / "r.json").read_text() == "1" and (out / "fig/x.png").read_text() == "2"
    assert json.loads((out / MANIFEST).read_text())["files"] == ["fig/x.png", "r.json"]
    assert [p.name for p in tmp_path.joinpath("a").iterdir()] == ["out"]  # no temporary sibling left


def test_existing_nonempty_refused_without_force(tmp_path):
    (tmp_path / "user.txt").write_text("mine")
    with pytest.raises(OutputError, match=f"^output directory {tmp_path}: exists and is not empty; choose another or pass --force$"):
        write_output(tmp_path, False, _write({"r.json": "1"}))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["user.txt"]


def test_force_removes_only_what_dualid_wrote(tmp_path):
    out = tmp_path / "out"
    write_output(out, False, _write({"old.json": "1", "sub/old.png": "2"}))
    (out / "notes.txt").write_text("keep me")
    write_output(out, True, _write({"new.json": "3"}))
    assert sorted(str(p.relative_to(out)) for p in out.rglob("*")) == [MANIFEST, "new.json", "notes.txt"]
    assert (out / "notes.txt").read_text() == "keep me"


def test_force_refuses_to_overwrite_a_foreign_file(tmp_path):
    (tmp_path / "r.json").write_text("user data")
    with pytest.raises(OutputError, match=r"would overwrite files that dualid did not write: \['r.json'\]"):
        write_output(tmp_path, True, _write({"r.json": "1"}))
    assert (tmp_path / "r.json").read_text() == "user data"


def test_failed_run_leaves_no_output(tmp_path):
    out = tmp_path / "out"
    with pytest.raises(RuntimeError, match="boom"):
        with output_dir(out) as d:
            (d / "half.json").write_text("{")
            raise RuntimeError("boom")
    assert not out.exists() and list(tmp_path.iterdir()) == []
    write_output(out, False, _write({"a": "1"}))
    with pytest.raises(RuntimeError):
        with output_dir(out, force=True) as d:
            (d / "b").write_text("2")
            raise RuntimeError("boom")
    assert sorted(p.name for p in out.iterdir()) == [MANIFEST, "a"]


def test_output_path_is_a_file(tmp_path):
    f = tmp_path / "f"
    f.write_text("x")
    with pytest.raises(OutputError, match=f"^output directory {f}: exists and is a file, expected a directory$"):
        write_output(f, True, _write({"a": "1"}))


def test_a_script_output_file_is_not_replaced_without_force(tmp_path):
    """A benchmark's result files: an existing one is named and refused before any work; with force it may be
    replaced, and missing directories are made."""
    kept = tmp_path / "results.json"
    kept.write_text("{}")
    new = tmp_path / "sub" / "results.md"
    with pytest.raises(OutputError, match="results.json: exists; pass --force to replace it"):
        check_output_files([kept, new], force=False)
    assert kept.read_text() == "{}" and not new.parent.exists()
    assert check_output_files([kept, new], force=True) == [kept, new] and new.parent.is_dir()


def test_a_script_given_its_parser_exits_with_its_usage(tmp_path, capsys):
    """With the script's argparse parser the refusal is the parser's error: exit status 2, the usage, the files."""
    import argparse

    kept = tmp_path / "results.json"
    kept.write_text("{}")
    parser = argparse.ArgumentParser(prog="bench")
    with pytest.raises(SystemExit) as exit_:
        check_output_files([kept], False, parser)
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("usage: bench") and "results.json: exists; pass --force to replace it" in err
    assert kept.read_text() == "{}"
