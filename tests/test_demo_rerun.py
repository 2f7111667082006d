"""`make demo` twice: the demo replaces a folder an earlier demo wrote (marked by its manifest.json listing every
file), whole and in one step, and still refuses any other non-empty folder without --overwrite."""

import json

import pytest

from seaice_jax.cli import main
from seaice_jax.errors import SeaiceError
from seaice_jax.outputs import MANIFEST, foreign_output, output_folder, write_manifest
from seaice_jax.workflows.demo import DEMO_COMMAND, demo_may_replace, run_demo


def _fake_demo(target, text, command=DEMO_COMMAND):
    """A folder written as the demo writes its own: files, then the manifest, moved into place as one run."""
    with output_folder(target, demo_may_replace(target)) as folder:
        (folder.path / "sequence").mkdir()
        (folder.path / "map.png").write_text(text)
        (folder.path / "sequence" / f"{text}.csv").write_text(text)
        write_manifest(folder, command)


def test_a_second_run_replaces_its_own_folder_whole(tmp_path):
    out = tmp_path / "seaice-demo"
    assert demo_may_replace(out) is False  # absent: nothing to replace
    _fake_demo(out, "first")
    manifest = json.loads((out / MANIFEST).read_text())
    assert manifest["command"] == DEMO_COMMAND
    assert manifest["files"] == [MANIFEST, "map.png", "sequence/first.csv"]
    assert foreign_output(out, DEMO_COMMAND) is None and demo_may_replace(out) is True
    _fake_demo(out, "second")  # no --overwrite
    assert (out / "map.png").read_text() == "second"
    assert not (out / "sequence" / "first.csv").exists()  # replaced whole, not merged
    assert sorted(p.name for p in tmp_path.iterdir()) == ["seaice-demo"]  # no temporary folder or lock left


@pytest.mark.parametrize(("prepare", "reason"), [
    (lambda out: (out / "thesis.tex").write_text("mine"), r"it has no manifest.json"),
    (lambda out: (_fake_demo(out, "first"), (out / "sequence" / "notes.txt").write_text("mine")),
     r"it holds sequence/notes.txt, which seaice demo did not write"),
    (lambda out: _fake_demo(out, "first", command="seaice remap"), r"its manifest.json says 'seaice remap' wrote it"),
    (lambda out: (_fake_demo(out, "first"), (out / MANIFEST).write_text("{")), r"its manifest.json is not readable"),
])
def test_any_other_folder_is_refused_before_the_demo_runs(tmp_path, capsys, prepare, reason):
    out = tmp_path / "out"
    out.mkdir()
    prepare(out)
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    with pytest.raises(SeaiceError, match=rf"out: not a folder an earlier `seaice demo` wrote \({reason}"):
        run_demo(out)
    assert main(["demo", "--out", str(out)]) == 2
    assert "pass --overwrite to replace it whole" in capsys.readouterr().err
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before
    assert demo_may_replace(out, overwrite=True) is True
