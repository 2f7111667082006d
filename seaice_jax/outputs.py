"""One run, one output: a command's folder (or file) is written into a temporary folder beside it and moved into
place only when complete.

The policy, for every command that writes:

- an existing target is refused unless ``overwrite`` (``--overwrite``); with it the target is replaced whole, never
  merged (an empty existing folder counts as absent);
- a lock (``.NAME.lock`` beside the target, an ``flock`` the kernel releases when the process dies) refuses a second
  run into the same target while one is writing, with an error naming the target;
- SIGINT and SIGTERM while the run holds its target raise :class:`Interrupted` (remembered, so one swallowed by a
  callback is raised again before the result is moved into place, and an error a library raised in its place is
  reported as the interrupt); the target is then left as it was (the old complete result, or nothing) and the
  temporary folder is removed;
- temporary folders left by a killed (SIGKILL) run are removed by the next run into the same target;
- a read-only target (or parent folder) is refused before anything runs, even an empty folder and even for a
  superuser; a target folder given as a symbolic link to a folder is written into the folder it links to (the link
  is kept);
- a disk (or quota, or file-size limit) that cannot take the output stops the run with an ``OSError`` naming the
  target and saying that it was left as it was.

The move into place is one ``rename`` (``renameat2(RENAME_EXCHANGE)`` when replacing a folder, where the C library
has it), with SIGINT and SIGTERM held back while it runs.
"""

import contextlib
import ctypes
import dataclasses
import errno
import fcntl
import os
import shutil
import signal
import sys
import tempfile
import threading
from collections.abc import Iterable, Iterator
from pathlib import Path

from seaice_jax.errors import SeaiceError
from seaice_jax.files import current_umask

_SIGNALS = (signal.SIGINT, signal.SIGTERM)
_pending: list[int] = []
"""Signals received while :func:`interrupts_raise` is active, in order (cleared when it is entered afresh)."""


class Interrupted(KeyboardInterrupt):
    """A SIGINT or SIGTERM stopped the run (a ``KeyboardInterrupt``, so ``except Exception`` does not swallow it).

    Attributes:
        signum: the signal's number. exit_code: ``128 + signum`` (130 for Ctrl-C, 143 for SIGTERM).
    """

    def __init__(self, signum: int):
        super().__init__(f"interrupted by {signal.Signals(signum).name}")
        self.signum = signum
        self.exit_code = 128 + signum
        self.left: list[Path] = []
        """Temporary folders the interrupted run could not remove (the next run into the same target does)."""


def check_interrupted() -> None:
    """Raise :class:`Interrupted` if a signal arrived (even one whose exception was swallowed, e.g. raised inside a
    garbage-collection callback) since :func:`interrupts_raise` was entered."""
    if _pending:
        raise Interrupted(_pending[-1])


def _raise_interrupted(signum, frame):
    """Record the signal and raise :class:`Interrupted`, unless a module is being imported: then the next
    :func:`check_interrupted` raises it (an exception raised inside the import of jaxlib's compiled extension left
    it half made, and the interpreter crashed (SIGSEGV) on its way out: 1 Ctrl-C in 10 while JAX loaded, on a
    loaded machine)."""
    _pending.append(signum)
    if not _importing(frame):
        raise Interrupted(signum)


def _importing(frame) -> bool:
    """Whether the Python ``frame`` or one of its callers runs Python's import machinery."""
    while frame is not None:
        if frame.f_code.co_filename.startswith("<frozen importlib"):
            return True
        frame = frame.f_back
    return False


@contextlib.contextmanager
def interrupts_raise() -> Iterator[None]:
    """While the block runs, SIGINT and SIGTERM raise :class:`Interrupted` (SIGTERM's default would kill the process
    without cleaning up); :func:`check_interrupted` runs when the block ends. A no-op outside the main thread."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    outermost = all(signal.getsignal(s) is not _raise_interrupted for s in _SIGNALS)
    if outermost:
        _pending.clear()
    previous = {s: signal.signal(s, _raise_interrupted) for s in _SIGNALS}
    try:
        with _signal_wins():
            yield
        check_interrupted()
    finally:
        for s, handler in previous.items():
            signal.signal(s, signal.SIG_DFL if handler is None else handler)


@contextlib.contextmanager
def _signal_wins() -> Iterator[None]:
    """An error raised after a signal arrived is reported as the :class:`Interrupted` it is (chained): a library may
    turn the signal's exception into another (numpy's ``tofile``, interrupted while writing an ``.npy``, raises
    ``TypeError: expected str, bytes or os.PathLike object, not BufferedWriter``)."""
    try:
        yield
    except Exception as error:
        if _pending:
            raise Interrupted(_pending[-1]) from error
        raise


@contextlib.contextmanager
def _signals_held() -> Iterator[None]:
    """SIGINT and SIGTERM are delivered only after the block (which must not be cut in half)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    signal.pthread_sigmask(signal.SIG_BLOCK, _SIGNALS)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_UNBLOCK, _SIGNALS)


@dataclasses.dataclass(frozen=True)
class OutputFolder:
    """Where a run writes: ``path`` (the temporary folder) and ``target`` (where it goes when complete)."""

    path: Path
    target: Path

    folder: bool = True

    def final(self, paths: Iterable[str | os.PathLike]) -> tuple[Path, ...]:
        """``paths`` written under :attr:`path`, as they will be named under :attr:`target` (a single-file target:
        the file ``path / target.name`` becomes ``target`` itself)."""
        base = self.target if self.folder else self.target.parent
        return tuple(base / Path(p).relative_to(self.path) for p in paths)


def _lock(target: Path) -> int:
    """Take the lock of ``target`` (a file descriptor holding an exclusive ``flock``).

    Raises:
        SeaiceError: naming ``target``, when another run holds it.
    """
    lock = target.parent / f".{target.name}.lock"
    while True:
        handle = os.open(lock, os.O_CREAT | os.O_RDWR, 0o644)
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(handle)
            raise SeaiceError(f"{target}: another run is writing into it now (lock {lock}); wait for it to finish "
                              "or choose another output") from None
        try:
            if os.stat(lock).st_ino == os.fstat(handle).st_ino:
                return handle
        except FileNotFoundError:
            pass
        os.close(handle)  # the previous holder removed the lock file as we opened it: take the new one


def _unlock(target: Path, handle: int) -> None:
    with contextlib.suppress(FileNotFoundError):
        os.unlink(target.parent / f".{target.name}.lock")
    os.close(handle)


def _leftovers(target: Path) -> list[Path]:
    """Temporary folders of earlier runs into ``target`` (only called while holding its lock)."""
    prefix = f".{target.name}."
    return [target.parent / name for name in os.listdir(target.parent)
            if name.startswith(prefix) and name.endswith((".partial", ".old"))]


def _occupied(target: Path) -> bool:
    """Whether ``target`` holds a result (a file, or a folder that is not empty)."""
    if target.is_dir() and not target.is_symlink():
        return any(os.scandir(target))
    return os.path.lexists(target)


def _inside(path: Path, folder: Path) -> bool:
    return path == folder or folder in path.parents


def _followed(target: Path, folder: bool) -> Path:
    """``target`` (absolute), or for a folder given as a symbolic link to a folder, the folder it links to (the
    result is written there and the link is kept).

    Raises:
        SeaiceError: naming ``target``: a link to nothing (or to a file, for a folder).
    """
    target = Path(target).absolute()
    if not (folder and target.is_symlink()):
        return target
    linked = Path(os.path.realpath(target))
    if not linked.is_dir():
        what = "a file" if linked.exists() else "nothing (a broken link)"
        raise SeaiceError(f"{target}: is a link to {linked}, which is {what}, not a folder; choose another output "
                          "folder")
    return linked


def _read_only(path: Path) -> bool:
    """Whether ``path`` is read-only: no write permission bit at all (respected even by a superuser's run, whose
    ``access`` check would pass), or not writable by this process (a read-only file system)."""
    return not os.stat(path).st_mode & 0o222 or not os.access(path, os.W_OK)


def _check_writable(target: Path, folder: bool) -> None:
    """Refuse a read-only target (an existing folder or file) or a target whose parent folder cannot take the
    temporary folder and the final rename.

    Raises:
        PermissionError: naming the target (an output that cannot be written: exit code 1).
    """
    kind = "folder" if folder else "file"
    if os.path.lexists(target) and _read_only(target):
        raise PermissionError(errno.EACCES, f"{target}: is read-only (Permission denied); make it writable or "
                                            f"choose another output {kind}")
    parent = next((p for p in target.parents if p.exists()), None)
    if parent is not None and (not parent.is_dir() or _read_only(parent) or not os.access(parent, os.X_OK)):
        raise PermissionError(errno.EACCES, f"{target}: cannot be created, {parent} is not a writable folder "
                                            f"(Permission denied); choose another output {kind}")


def _check_target(target: Path, folder: bool, overwrite: bool, inputs: Iterable[str | os.PathLike]) -> None:
    """Refuse a target that is not of the right kind, that is read-only or whose parent is, that holds a result
    (unless ``overwrite``), or that contains an input or the working folder (replacing it would destroy them)."""
    if folder and os.path.lexists(target) and (not target.is_dir() or target.is_symlink()):
        raise SeaiceError(f"{target}: exists and is not a folder; choose another output folder")
    if not folder and target.is_dir():
        raise SeaiceError(f"{target}: is a folder; give a file name")
    _check_writable(target, folder)
    resolved = target.resolve()
    for source in inputs:
        if _inside(Path(source).resolve(), resolved):
            raise SeaiceError(f"{target}: contains the input {source}; write the results into another folder")
    if _inside(Path.cwd().resolve(), resolved) and _occupied(target):
        raise SeaiceError(f"{target}: contains the working folder; write the results into another folder")
    if not overwrite and _occupied(target):
        what = "folder is not empty" if folder else "file exists"
        raise SeaiceError(f"{target}: the {what}; pass --overwrite to replace it whole (overwrite=True)")


def _exchange(first: Path, second: Path) -> bool:
    """Swap two folders in one step (Linux ``renameat2(RENAME_EXCHANGE)``); False where the system cannot."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        renameat2 = libc.renameat2
    except (OSError, AttributeError):
        return False
    at_cwd, rename_exchange = -100, 2
    if renameat2(at_cwd, os.fsencode(first), at_cwd, os.fsencode(second), rename_exchange) == 0:
        return True
    if ctypes.get_errno() in (errno.ENOSYS, errno.EINVAL, errno.ENOTSUP):
        return False
    raise OSError(ctypes.get_errno(), os.strerror(ctypes.get_errno()), str(second))


def _move_into_place(staging: Path, target: Path, folder: bool) -> None:
    """Replace ``target`` by the finished result in ``staging`` (the folder itself, or the one file in it)."""
    if not folder:
        os.replace(staging / target.name, target)
        shutil.rmtree(staging)
        return
    if os.path.isdir(target) and any(os.scandir(target)):
        if not _exchange(staging, target):
            old = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".old", dir=target.parent))
            os.replace(target, old)
            os.replace(staging, target)
            staging = old
        shutil.rmtree(staging)
    else:
        os.replace(staging, target)


_FULL = (errno.ENOSPC, errno.EFBIG, errno.EDQUOT)
"""Errors of a disk (or quota, or file-size limit) that cannot take the output."""


@contextlib.contextmanager
def _output(target: str | os.PathLike, folder: bool, overwrite: bool,
            inputs: Iterable[str | os.PathLike]) -> Iterator[OutputFolder]:
    target = _followed(Path(target), folder)
    _check_target(target, folder, overwrite, inputs)
    target.parent.mkdir(parents=True, exist_ok=True)
    handle = staging = None
    with interrupts_raise():
        try:
            with _signals_held():
                handle = _lock(target)
                for leftover in _leftovers(target):
                    shutil.rmtree(leftover, ignore_errors=True)
                staging = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".partial", dir=target.parent))
                os.chmod(staging, 0o777 & ~current_umask())
            _check_target(target, folder, overwrite, ())
            check_interrupted()  # one swallowed while the run started (e.g. by a garbage-collection callback)
            try:
                with _signal_wins():  # before the cleanup below, which records what it left on an Interrupted
                    yield OutputFolder(staging, target, folder)
                check_interrupted()
                with _signals_held():
                    _move_into_place(staging, target, folder)
            except OSError as error:
                if error.errno not in _FULL:
                    raise
                left = "left as it was" if os.path.lexists(target) else "not created"
                raise OSError(error.errno, f"{target}: could not be written ({error.strerror}); the output was "
                                           f"{left} and nothing partial was kept; free some space (or raise the "
                                           "limit) or choose another output") from error
        finally:
            with _signals_held():
                if staging is not None:
                    for _ in range(3):  # a straggling writer may have made it again
                        shutil.rmtree(staging, ignore_errors=True)
                        if not os.path.lexists(staging):
                            break
                    else:
                        stopped = sys.exc_info()[1]
                        if isinstance(stopped, Interrupted):
                            stopped.left.append(staging)
                if handle is not None:
                    _unlock(target, handle)


def check_output(target: str | os.PathLike, overwrite: bool = False, inputs: Iterable[str | os.PathLike] = (),
                 folder: bool = True) -> None:
    """Refuse ``target`` now, before any computation, as :func:`output_folder` (``folder``) or :func:`output_file`
    would when the result is ready to be written (they check again then).

    Raises:
        SeaiceError: naming ``target``: not of the right kind, not empty (without ``overwrite``), or containing an
            input or the working folder.
    """
    check_interrupted()
    _check_target(_followed(Path(target), folder), folder, overwrite, inputs)


def output_folder(target: str | os.PathLike, overwrite: bool = False,
                  inputs: Iterable[str | os.PathLike] = ()) -> contextlib.AbstractContextManager[OutputFolder]:
    """Write a run's folder: yields an :class:`OutputFolder` whose ``path`` (a temporary folder beside ``target``)
    the block fills; when the block ends without error the folder becomes ``target``.

    Args:
        target: the output folder. overwrite: replace an existing non-empty folder whole (else refused).
        inputs: files the run reads; a target containing one is refused.

    Raises:
        SeaiceError: naming ``target``: not a folder, not empty (without ``overwrite``), containing an input or the
            working folder, or locked by another run. PermissionError: naming ``target``: read-only, or in a
            folder that is.
        Interrupted: on SIGINT or SIGTERM during the block (``target`` left as it was).
    """
    return _output(target, True, overwrite, inputs)


def output_file(target: str | os.PathLike, overwrite: bool = False,
                inputs: Iterable[str | os.PathLike] = ()) -> contextlib.AbstractContextManager[OutputFolder]:
    """As :func:`output_folder`, for a single file: the block writes ``path / target.name``, which replaces
    ``target`` when the block ends without error."""
    return _output(target, False, overwrite, inputs)


MANIFEST = "manifest.json"
"""The file a command writes into its output folder to mark the folder as its own: the command and every file it
wrote (:func:`write_manifest`)."""
_MANIFEST_FORMAT = "seaice_jax output manifest"


def write_manifest(folder: OutputFolder, command: str) -> Path:
    """Write :data:`MANIFEST` into ``folder.path`` (call it last): the ``command`` that made the output and every
    file under ``folder.path`` (the manifest itself included), so that a later run of the same command may recognise
    the folder as its own (:func:`foreign_output`).

    Returns:
        the manifest's final path (under ``folder.target``).
    """
    from seaice_jax import __version__
    from seaice_jax.files import write_json

    names = sorted(_files_under(folder.path) | {MANIFEST})
    write_json(folder.path / MANIFEST, {"format": _MANIFEST_FORMAT, "command": command, "version": __version__,
                                        "files": names})
    return folder.target / MANIFEST


def _files_under(folder: Path) -> set[str]:
    """Every file (and link) under ``folder`` as a POSIX path relative to it (folders themselves are not listed)."""
    names = set()
    for root, dirs, files in os.walk(folder):
        for name in files + [d for d in dirs if os.path.islink(os.path.join(root, d))]:
            names.add(Path(root, name).relative_to(folder).as_posix())
    return names


def foreign_output(target: str | os.PathLike, command: str) -> str | None:
    """Why ``target`` is not an output folder that ``command`` wrote and may replace: ``None`` when it is absent,
    empty, or holds exactly the files its :data:`MANIFEST` lists, written by ``command``; else the reason (no
    manifest, another command's, or a file the manifest does not list, e.g. one a user added)."""
    import json

    target = Path(os.path.realpath(target)) if Path(target).is_dir() else Path(target)  # a link: the folder
    if not _occupied(target):
        return None
    if not target.is_dir():
        return "it is not a folder"
    manifest = target / MANIFEST
    try:
        document = json.loads(manifest.read_text(encoding="utf-8"))
    except FileNotFoundError:
        return f"it has no {MANIFEST}"
    except (OSError, UnicodeDecodeError, ValueError) as error:
        return f"its {MANIFEST} is not readable ({error})"
    if not isinstance(document, dict) or document.get("format") != _MANIFEST_FORMAT:
        return f"its {MANIFEST} is not a seaice_jax output manifest"
    if document.get("command") != command:
        return f"its {MANIFEST} says {document.get('command')!r} wrote it"
    listed = document.get("files")
    if not isinstance(listed, list):
        return f"its {MANIFEST} lists no files"
    extra = sorted(_files_under(target) - {str(name) for name in listed})
    if extra:
        return f"it holds {extra[0]}, which {command} did not write" + (f" (and {len(extra) - 1} more)"
                                                                          if len(extra) > 1 else "")
    return None
