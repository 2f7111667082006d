"""One run, one output folder (seaice_jax.outputs): re-run, different run, interrupted run and concurrent runs leave
either the old complete result or the new complete result, never a mix, and no temporary files."""

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from seaice_jax.cli import CACHE_VARIABLE, main
from seaice_jax.errors import SeaiceError
from seaice_jax.outputs import Interrupted, check_interrupted, interrupts_raise, output_file, output_folder

ROOT = Path(__file__).resolve().parents[1]


def _content(path: Path) -> bytes:
    """A file's bytes; for NetCDF the values of its variables (the file also holds the time it was created)."""
    if path.suffix != ".nc":
        return path.read_bytes()
    with xr.open_dataset(path) as data:
        return b"".join(np.ascontiguousarray(data[k].values).tobytes() for k in sorted(map(str, data.variables)))


def _tree(folder: Path) -> dict[str, bytes]:
    """``{relative path: content}`` of every file under ``folder``."""
    return {str(p.relative_to(folder)): _content(p) for p in sorted(folder.rglob("*")) if p.is_file()}


def _clean(parent: Path) -> None:
    """No temporary folder, partial file or lock left beside the outputs."""
    left = [p.name for p in parent.rglob("*") if p.name.startswith(".") or p.name.endswith((".part", ".partial"))]
    assert left == []


def _write(folder, files: dict[str, str]):
    for name, text in files.items():
        (folder.path / name).write_text(text)


def test_new_folder_appears_only_when_complete(tmp_path):
    target = tmp_path / "out"
    with output_folder(target) as folder:
        _write(folder, {"a.csv": "1\n"})
        assert not target.exists()
        assert folder.final([folder.path / "a.csv"]) == (target.absolute() / "a.csv",)
    assert _tree(target) == {"a.csv": b"1\n"}
    _clean(tmp_path)


def test_existing_folder_refused_without_overwrite_and_replaced_whole_with_it(tmp_path):
    target = tmp_path / "out"
    with output_folder(target) as folder:
        _write(folder, {"old_only.csv": "old\n", "shared.csv": "old\n"})
    with pytest.raises(SeaiceError, match=r"out: the folder is not empty; pass --overwrite"):
        with output_folder(target) as folder:
            _write(folder, {"shared.csv": "new\n"})
    assert _tree(target) == {"old_only.csv": b"old\n", "shared.csv": b"old\n"}
    with output_folder(target, overwrite=True) as folder:
        _write(folder, {"shared.csv": "new\n"})
    assert _tree(target) == {"shared.csv": b"new\n"}  # a different run: nothing of the old one is left
    _clean(tmp_path)


def test_an_empty_existing_folder_is_used(tmp_path):
    (tmp_path / "empty").mkdir()
    with output_folder(tmp_path / "empty") as folder:
        _write(folder, {"a.csv": "1\n"})
    assert _tree(tmp_path / "empty") == {"a.csv": b"1\n"}


def test_failed_run_leaves_the_old_result(tmp_path):
    target = tmp_path / "out"
    with output_folder(target) as folder:
        _write(folder, {"a.csv": "old\n"})
    with pytest.raises(RuntimeError, match="half way"), output_folder(target, overwrite=True) as folder:
        _write(folder, {"a.csv": "new\n", "b.csv": "new\n"})
        raise RuntimeError("half way")
    assert _tree(target) == {"a.csv": b"old\n"}
    _clean(tmp_path)


def test_folder_containing_an_input_or_a_file_in_the_way_is_refused(tmp_path):
    project = tmp_path / "project"
    project.mkdir()
    (project / "project.toml").write_text("")
    with pytest.raises(SeaiceError, match="contains the input"), output_folder(project, True,
                                                                               inputs=[project / "project.toml"]):
        pass
    assert (project / "project.toml").exists()
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(SeaiceError, match="file: exists and is not a folder"), output_folder(blocker):
        pass
    with pytest.raises(SeaiceError, match="project: is a folder"), output_file(project):
        pass


def test_output_file_policy(tmp_path):
    target = tmp_path / "report.json"
    with output_file(target) as staging:
        (staging.path / target.name).write_text("old")
    with pytest.raises(SeaiceError, match="report.json: the file exists; pass --overwrite"), output_file(target):
        pass
    with output_file(target, overwrite=True) as staging:
        (staging.path / target.name).write_text("new")
    assert target.read_text() == "new"
    _clean(tmp_path)


def test_second_run_into_a_locked_folder_is_refused_by_name(tmp_path):
    target = tmp_path / "out"
    with output_folder(target) as folder:
        _write(folder, {"a.csv": "first\n"})
        with pytest.raises(SeaiceError, match=r"out: another run is writing into it now"):
            with output_folder(target, overwrite=True) as other:
                _write(other, {"a.csv": "second\n"})
    assert _tree(target) == {"a.csv": b"first\n"}
    _clean(tmp_path)


def test_leftovers_of_a_killed_run_are_removed_by_the_next(tmp_path):
    leftover = tmp_path / ".out.abc123.partial"
    leftover.mkdir()
    (leftover / "a.csv").write_text("half")
    with output_folder(tmp_path / "out") as folder:
        _write(folder, {"a.csv": "1\n"})
    _clean(tmp_path)


_SLOW_WRITER = textwrap.dedent("""
    import sys, time
    from pathlib import Path
    from seaice_jax.outputs import Interrupted, output_folder
    try:
        with output_folder(sys.argv[1], overwrite=True) as folder:
            for k in range(3):
                (folder.path / f"part{k}.csv").write_text("new\\n")
            print("writing", flush=True)
            time.sleep(60)
            (folder.path / "last.csv").write_text("new\\n")
    except Interrupted as interrupt:
        print(interrupt, file=sys.stderr)
        sys.exit(interrupt.exit_code)
""")


@pytest.mark.parametrize(("signum", "code"), [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_signal_while_writing_leaves_the_old_result_and_no_temporary_files(tmp_path, signum, code):
    target = tmp_path / "out"
    with output_folder(target) as folder:
        _write(folder, {"old.csv": "old\n"})
    process = subprocess.Popen([sys.executable, "-c", _SLOW_WRITER, str(target)], stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True, cwd=ROOT)
    assert process.stdout is not None and process.stdout.readline() == "writing\n"
    assert any(p.name.endswith(".partial") for p in tmp_path.iterdir())  # it really is half way
    process.send_signal(signum)
    _, error = process.communicate(timeout=60)
    assert process.returncode == code
    assert signal.Signals(signum).name in error
    assert _tree(target) == {"old.csv": b"old\n"}
    _clean(tmp_path)


def test_a_swallowed_ctrl_c_is_not_lost(tmp_path):
    """A KeyboardInterrupt raised inside a finaliser (as in a garbage-collection callback) is printed and dropped by
    Python; the run must still stop with 130 before its result is moved into place."""
    script = textwrap.dedent("""
        import os, signal, sys
        from seaice_jax.outputs import Interrupted, output_folder

        class Finaliser:
            def __del__(self):
                os.kill(os.getpid(), signal.SIGINT)
                sum(range(1000))  # the handler runs here, inside __del__: its exception is swallowed

        try:
            with output_folder(sys.argv[1]) as folder:
                (folder.path / "a.csv").write_text("1")
                finaliser = Finaliser()
                del finaliser
                print("went on", flush=True)
        except Interrupted as interrupt:
            sys.exit(interrupt.exit_code)
    """)
    target = tmp_path / "out"
    done = subprocess.run([sys.executable, "-c", script, str(target)], capture_output=True, text=True, cwd=ROOT,
                          timeout=60)
    assert "went on" in done.stdout and "Exception ignored" in done.stderr  # the exception was swallowed...
    assert done.returncode == 130  # ...and the interrupt still stopped the run
    assert not target.exists()
    _clean(tmp_path)


@pytest.fixture(scope="module")
def seaice(tmp_path_factory):
    """Start ``seaice`` commands sharing one persistent compilation cache (the first run fills it, later runs of the
    same command skip XLA's compilations): the test session's (tests/conftest.py), or one of their own when the
    session runs without."""
    environment = {**os.environ, CACHE_VARIABLE: os.environ.get(CACHE_VARIABLE) or str(
        tmp_path_factory.mktemp("jax_cache"))}

    def start(*args, **kwargs):
        return subprocess.Popen([sys.executable, "-m", "seaice_jax.cli", *args], stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True, cwd=ROOT, env=environment, **kwargs)
    return start


SMALL = ("simulate", "lancaster", "--images", "2", "--size", "48")


@pytest.fixture(scope="module")
def reference(tmp_path_factory, seaice) -> dict[str, bytes]:
    """The complete result of the small command, run alone."""
    folder = tmp_path_factory.mktemp("reference") / "out"
    process = seaice(*SMALL, "--out", str(folder))
    _, error = process.communicate(timeout=600)
    assert process.returncode == 0, error
    return _tree(folder)


@pytest.mark.slow
def test_cli_rerun_different_run_and_two_runs_at_once(tmp_path, reference, seaice):
    """A folder of another run is refused without ``--overwrite``; two runs with it, started at once, leave the
    complete result of one of them (the other finds the folder locked, or runs after it) and nothing of the other
    run's files."""
    target = tmp_path / "out"
    process = seaice("examples", str(target))  # a different run (no compilation: the example files)
    _, error = process.communicate(timeout=600)
    assert process.returncode == 0, error
    other = _tree(target)
    assert set(other) - set(reference)  # the other run wrote files the small one does not
    again = seaice(*SMALL, "--out", str(target))
    _, error = again.communicate(timeout=600)
    assert again.returncode == 2 and f"{target}: the folder is not empty; pass --overwrite" in error
    assert _tree(target) == other
    processes = [seaice(*SMALL, "--out", str(target), "--overwrite") for _ in range(2)]
    results = [(p.communicate(timeout=600)[1], p.returncode) for p in processes]
    for error, code in results:
        assert code == 0 or (code == 2 and f"{target}: another run is writing into it now" in error), error
    assert any(code == 0 for _, code in results)
    assert _tree(target) == reference  # no file of the other run is left beside the new one
    _clean(tmp_path)


def _wait_for_staging(parent: Path, process, timeout: float = 600.0) -> bool:
    """Poll until a temporary folder beside the output holds a file (the run is writing)."""
    end = time.monotonic() + timeout
    while time.monotonic() < end and process.poll() is None:
        if any(any(p.iterdir()) for p in parent.iterdir() if p.name.endswith(".partial")):
            return True
        time.sleep(0.001)
    return False


@pytest.mark.slow
def test_cli_terminated_while_writing(tmp_path, reference, seaice):
    target = tmp_path / "out"
    process = seaice(*SMALL, "--out", str(target))
    if _wait_for_staging(tmp_path, process):
        process.send_signal(signal.SIGTERM)
    _, error = process.communicate(timeout=600)
    assert process.returncode in (0, 143), error  # 0 only if it finished before the signal landed
    assert _tree(target) == reference if process.returncode == 0 else not target.exists()
    if process.returncode == 143:
        assert "interrupted by SIGTERM" in error
    _clean(tmp_path)


def test_an_error_a_library_raises_in_place_of_the_signal_is_the_interrupt(tmp_path):
    """A library may turn the signal's exception into another: numpy's ``tofile``, hit by SIGTERM while ``seaice
    simulate`` wrote an ``.npy``, raised a TypeError and the run ended as an "unexpected error" (exit 1). The run
    must stop as interrupted (143, the error chained) with the target untouched."""
    target = tmp_path / "out"

    def library_write(path):
        try:
            path.write_bytes(b"half")
            signal.raise_signal(signal.SIGTERM)
        except KeyboardInterrupt:
            raise TypeError("expected str, bytes or os.PathLike object, not BufferedWriter") from None

    with pytest.raises(Interrupted) as raised, output_folder(target) as folder:
        library_write(folder.path / "a.npy")
    assert raised.value.exit_code == 143 and isinstance(raised.value.__cause__, TypeError)
    assert not target.exists() and not list(tmp_path.iterdir())
    with pytest.raises(TypeError), output_folder(target):  # without a signal the library's error is what it is
        raise TypeError("a real one")
    _clean(tmp_path)


def test_interrupted_is_a_keyboard_interrupt():
    assert issubclass(Interrupted, KeyboardInterrupt) and Interrupted(signal.SIGINT).exit_code == 130


@pytest.mark.parametrize("scenario", ["aidjex", "prudhoe", "lancaster"])
def test_simulate_refuses_an_existing_folder_before_loading_the_simulation(tmp_path, scenario):
    """The policy is checked before minutes of simulation: the simulator's modules are not even imported."""
    target = tmp_path / "out"
    target.mkdir()
    (target / "keep.txt").write_text("old\n")
    script = (f"import sys; from seaice_jax.cli import main; code = main(['simulate', {scenario!r}, '--out', "
              f"{str(target)!r}]); print(code, [m for m in sys.modules if m.startswith('seaice_jax.simulate')])")
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert run.stdout.split(None, 1) == ["2", "[]\n"], run.stderr
    assert f"{target}: the folder is not empty; pass --overwrite" in run.stderr
    assert _tree(target) == {"keep.txt": b"old\n"}
    _clean(tmp_path)


def test_a_read_only_folder_is_refused_even_when_empty(tmp_path, capsys):
    """An empty folder counts as absent, but a read-only one is the user's "do not touch": refused before anything
    runs (also for a superuser, whose writes the permission bits would not stop), and left as it was."""
    target = tmp_path / "out"
    target.mkdir()
    target.chmod(0o555)
    try:
        with pytest.raises(PermissionError, match=r"out: is read-only \(Permission denied\)"), output_folder(target):
            pass
        assert main(["examples", str(target), "--overwrite"]) == 1  # an output that cannot be written
        assert "out: is read-only (Permission denied)" in capsys.readouterr().err
        assert target.is_dir() and list(target.iterdir()) == [] and target.stat().st_mode & 0o777 == 0o555
        target.chmod(0o755)
        (tmp_path / "locked").mkdir(mode=0o555)
        with pytest.raises(PermissionError, match=r"locked/out: cannot be created, .*locked is not a writable folder"):
            with output_folder(tmp_path / "locked" / "out"):
                pass
    finally:
        for folder in (target, tmp_path / "locked"):
            if folder.exists():
                folder.chmod(0o755)
    _clean(tmp_path)


def test_a_linked_output_folder_is_followed(tmp_path, capsys):
    real = tmp_path / "real"
    real.mkdir()
    (tmp_path / "link").symlink_to(real)
    assert main(["examples", str(tmp_path / "link"), "-q"]) == 0
    assert (tmp_path / "link").is_symlink() and (real / "AGRID.STN").is_file()
    assert main(["examples", str(tmp_path / "link"), "-q"]) == 2  # the folder it links to holds a result now
    assert "the folder is not empty" in capsys.readouterr().err
    (tmp_path / "broken").symlink_to(tmp_path / "nowhere")
    with pytest.raises(SeaiceError, match=r"broken: is a link to .*nowhere, which is nothing \(a broken link\), not "
                                          r"a folder"), output_folder(tmp_path / "broken"):
        pass
    _clean(tmp_path)


_FULL_DISK = textwrap.dedent("""
    import resource, sys
    from seaice_jax.cli import main
    resource.setrlimit(resource.RLIMIT_FSIZE, (100, 100))  # no file past 100 bytes: the examples are 79-305
    sys.exit(main(["examples", sys.argv[1], "--overwrite"]))
""")


def _old_result(target: Path) -> dict[str, bytes]:
    with output_folder(target) as folder:
        _write(folder, {"old.csv": "old\n"})
    return _tree(target)


def test_a_file_size_limit_while_writing_leaves_the_output_untouched(tmp_path):
    """The file-size limit (RLIMIT_FSIZE) stands in for a full disk everywhere: the write fails half way (EFBIG),
    the run exits 1 naming the output and saying it was left as it was, and nothing partial is kept."""
    target = tmp_path / "out"
    old = _old_result(target)
    run = subprocess.run([sys.executable, "-c", _FULL_DISK, str(target)], capture_output=True, text=True, cwd=ROOT,
                         timeout=120)
    assert run.returncode == 1, run.stderr
    assert f"{target}: could not be written (File too large); the output was left as it was" in run.stderr
    assert "Traceback" not in run.stderr
    assert _tree(target) == old
    _clean(tmp_path)


@pytest.mark.skipif(not sys.platform.startswith("linux") or os.geteuid() != 0, reason="mounting a tmpfs needs root")
def test_a_full_disk_while_writing_leaves_the_output_untouched(tmp_path, capsys):
    """A real full disk (ENOSPC): a 64 KiB tmpfs, filled, then a run replacing its output."""
    disk = tmp_path / "disk"
    disk.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(disk)], capture_output=True).returncode:
        pytest.skip("cannot mount a tmpfs here")
    try:
        target = disk / "out"
        old = _old_result(target)
        (disk / "filler").write_bytes(b"\0" * 60_000)
        assert main(["examples", str(target), "--overwrite"]) == 1
        error = capsys.readouterr().err
        assert f"{target}: could not be written (No space left on device); the output was left as it was" in error
        assert _tree(target) == old
        assert main(["examples", str(disk / "new")]) == 1
        assert f"{disk / 'new'}: could not be written (No space left on device); the output was not created" in \
            capsys.readouterr().err
        assert sorted(p.name for p in disk.iterdir()) == ["filler", "out"]  # no staging folder, no lock
    finally:
        subprocess.run(["umount", str(disk)], check=True)


def test_a_ctrl_c_during_an_import_is_raised_after_it(tmp_path, monkeypatch):
    """Raised inside an import (jaxlib's compiled extension, while JAX loads), the interrupt left the module half
    made and the interpreter crashed on exit; now the import completes and the next check raises it."""
    module = "import os, signal\nos.kill(os.getpid(), signal.SIGINT)\ncomplete = True\n"
    (tmp_path / "slow_module.py").write_text(module)
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(Interrupted, match="SIGINT"), interrupts_raise():
        try:
            import slow_module
        except Interrupted:
            pytest.fail("the interrupt was raised inside the import")
        assert slow_module.complete
        check_interrupted()
    with pytest.raises(Interrupted, match="SIGINT"), interrupts_raise():  # outside an import: at once
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(5)
    sys.modules.pop("slow_module", None)
