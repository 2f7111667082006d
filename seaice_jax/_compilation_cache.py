"""JAX's persistent compilation cache, for Python users (:func:`enable_compilation_cache`, re-exported as
``seaice_jax.enable_compilation_cache``) and the ``seaice`` command (on by default, ``--no-compile-cache``).

JAX compiles every jitted function the first time it meets its shapes; with the cache on, those compilations are
kept on disk and a later process with the same shapes, JAX version and machine reads them instead of compiling
again (benchmarks/RESULTS.md, «Command line»: ``seaice block`` on the demo's project 17.4 s with an empty cache,
6.4 s with the first run's). Nothing here imports JAX until the cache is turned on, so that ``seaice --help`` stays
fast.
"""

import logging
import os
from pathlib import Path

from seaice_jax.errors import SeaiceError

CACHE_VARIABLE = "SEAICE_JAX_CACHE_DIR"
"""Environment variable naming the cache folder (an empty value turns the default cache off)."""

_log = logging.getLogger(__name__)


def default_cache_folder() -> Path | None:
    """The default folder of the compilation cache: ``$SEAICE_JAX_CACHE_DIR`` when set (empty: None, no cache),
    else ``$XDG_CACHE_HOME/seaice_jax/jax``, else ``~/.cache/seaice_jax/jax``."""
    if CACHE_VARIABLE in os.environ:
        return Path(os.environ[CACHE_VARIABLE]).expanduser() if os.environ[CACHE_VARIABLE] else None
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache").expanduser() / "seaice_jax" / "jax"


def enable_compilation_cache(path: str | os.PathLike | None = None) -> Path | None:
    """Turn on JAX's persistent compilation cache for this process, keeping every compilation however short, so
    that a later run (a new Python session, a script run again) reads them instead of compiling.

    Call it once, before the first jitted call: JAX sets its cache up at the first compilation and keeps that
    folder for the rest of the process. The ``seaice`` command does this itself.

    Args:
        path: the cache folder (created if missing). ``None``: :func:`default_cache_folder` —
            ``$SEAICE_JAX_CACHE_DIR`` if set, else ``$XDG_CACHE_HOME/seaice_jax/jax`` or
            ``~/.cache/seaice_jax/jax``; an empty ``$SEAICE_JAX_CACHE_DIR`` leaves the cache off.

    Returns:
        The folder in use, or None when the cache was left off (an empty ``$SEAICE_JAX_CACHE_DIR``).

    Raises:
        SeaiceError: naming the folder, when it cannot be created or written.

    Example:
        ``import seaice_jax as sj; sj.enable_compilation_cache()`` at the top of a script or notebook.
    """
    folder = Path(path).expanduser() if path is not None else default_cache_folder()
    if folder is None:
        _log.debug("compilation cache off (%s is empty)", CACHE_VARIABLE)
        return None
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise SeaiceError(f"{folder}: cannot be used as the compilation cache ({error.strerror or error}); give "
                          f"another folder (or set ${CACHE_VARIABLE})") from None
    if not os.access(folder, os.W_OK | os.X_OK):
        raise SeaiceError(f"{folder}: the compilation cache folder is not writable; give another folder (or set "
                          f"${CACHE_VARIABLE})")
    import jax

    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    _log.debug("compilation cache in %s", folder)
    return folder
