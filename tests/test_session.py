"""The session helpers for Python users: ``seaice_jax.enable_compilation_cache`` (JAX's persistent cache, kept
between processes) and the library's progress through :mod:`logging` (the ``seaice_jax`` loggers), which the
``seaice`` command prints as before."""

import logging
import os
import subprocess
import sys
from pathlib import Path

import pytest

import seaice_jax
from seaice_jax._compilation_cache import CACHE_VARIABLE
from seaice_jax.cli import NORMAL, QUIET, _library_logging, main
from seaice_jax.errors import SeaiceError
from seaice_jax.workflows.archive import workers_note
from seaice_jax.workflows.sar import run_geolocate

EW = Path(__file__).with_name("data") / "sentinel1" / \
    "s1a-ew1-slc-hh-20210403t122536-20210403t122628-037286-046484-001.xml"
JITTED = ("import jax, jax.numpy as jnp\n"
          "jax.jit(lambda x: jnp.sin(x) * 2.0 + x)(jnp.arange(5.0)).block_until_ready()\n")


def _python(script: str, **environment) -> subprocess.CompletedProcess:
    env = {key: value for key, value in os.environ.items() if key != CACHE_VARIABLE}
    return subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300,
                          env={**env, "JAX_PLATFORMS": "cpu", **environment})


def test_the_cache_folder_gets_the_compilations_of_a_jitted_call(tmp_path):
    cache = tmp_path / "given"
    result = _python(f"import seaice_jax as sj\nprint(sj.enable_compilation_cache({str(cache)!r}))\n{JITTED}")
    assert result.returncode == 0, result.stderr[-2000:]
    assert result.stdout.strip() == str(cache)
    assert any(p.is_file() and p.stat().st_size > 0 for p in cache.rglob("*"))


def test_the_default_folder_follows_the_environment(tmp_path):
    result = _python(f"import seaice_jax as sj\nprint(sj.enable_compilation_cache())\n{JITTED}",
                     XDG_CACHE_HOME=str(tmp_path / "xdg"))
    assert result.returncode == 0, result.stderr[-2000:]
    default = tmp_path / "xdg" / "seaice_jax" / "jax"
    assert result.stdout.strip() == str(default) and any(default.iterdir())
    result = _python(f"import seaice_jax as sj\nprint(sj.enable_compilation_cache())\n{JITTED}",
                     **{CACHE_VARIABLE: "", "XDG_CACHE_HOME": str(tmp_path / "off")})
    assert result.returncode == 0, result.stderr[-2000:]
    assert result.stdout.strip() == "None" and not (tmp_path / "off").exists()


def test_a_folder_that_cannot_be_made_is_named(tmp_path):
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    with pytest.raises(SeaiceError, match=r"a_file/cache: cannot be used as the compilation cache"):
        seaice_jax.enable_compilation_cache(blocker / "cache")


def test_workflow_stages_are_logged_without_a_say(tmp_path, caplog):
    with caplog.at_level(logging.INFO, logger="seaice_jax"):
        run_geolocate(EW, tmp_path / "ew")
    stages = [(r.name, r.levelno, r.getMessage()) for r in caplog.records if r.name.startswith("seaice_jax.")]
    assert stages[0][:2] == ("seaice_jax.workflows.sar", logging.INFO)
    assert stages[0][2].startswith("geolocating ") and ("seaice_jax.workflows.sar", logging.INFO,
                                                         "drawing the figure") in stages


def test_a_library_note_is_a_warning_record(caplog):
    with caplog.at_level(logging.WARNING, logger="seaice_jax"):
        note = workers_note(100_000, None, progress=False)
    assert note and [(r.name, r.levelno, r.getMessage()) for r in caplog.records] == [
        ("seaice_jax.workflows.archive", logging.WARNING, note)]


def test_the_command_prints_library_records_as_before_and_restores_logging(capsys, tmp_path):
    logger = logging.getLogger("seaice_jax")
    before = (logger.level, logger.propagate, list(logger.handlers))
    with _library_logging(NORMAL):
        logging.getLogger("seaice_jax.workflows.archive").warning("--workers 9: starting 2")
        logging.getLogger("seaice_jax.workflows.sar").debug("not shown without -v")
    with _library_logging(QUIET):
        logging.getLogger("seaice_jax.workflows.archive").warning("not shown with -q")
    assert capsys.readouterr().err == "seaice: --workers 9: starting 2\n"
    assert (logger.level, logger.propagate, list(logger.handlers)) == before
    # the command passes its own `say`: each stage once, in its usual form, and no logger line besides
    assert main(["sar", "geolocate", str(EW), "--out", str(tmp_path / "ew")]) == 0
    err = capsys.readouterr().err
    assert err.count("seaice sar [") == 2 and "seaice: " not in err
