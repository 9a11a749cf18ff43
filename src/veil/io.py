"""Every file and folder veil writes, written as a transaction (docs/errors.md).

- :func:`write_bytes_atomic`, :func:`write_text_atomic`: one file, through a temporary file
  in the same directory, synced, then renamed over the target. Readers see the old file or
  the new one, never half of one. A replaced file keeps its permissions; a new one gets
  those the umask gives.
- :func:`output_folder`: a folder of outputs (a pipeline's results, the paper's figures),
  written into a temporary folder and moved into place at the end. An interrupted or failed
  run leaves the earlier complete folder as it was, or nothing; never a mix of old and new
  files.

Temporaries are registered while they exist, so that the command line's interrupt handler
(:mod:`veil.cli.interrupts`) can remove them before the process exits
(:func:`abandon`), and commits (the final renames) hold :data:`COMMIT`, which that handler
takes first: an interrupt lands before a commit or after it, never inside one.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import os
import shutil
import stat
import tempfile
import threading
from collections.abc import Iterator
from pathlib import Path

from .errors import InputTypeError, NotAFileError, UnwritableError

#: Held while outputs are renamed into place; the interrupt handler acquires it (and never
#: releases it) before it removes the temporaries and exits.
COMMIT = threading.RLock()

_temporaries: dict[str, str] = {}  # path -> "file" | "folder", removed on interrupt
_folders: dict[str, bool] = {}  # output folders being written -> whether one existed
_written: list[str] = []  # complete outputs of this process, in order
_partial: dict[str, str] = {}  # resumable outputs kept on interrupt -> what to say
#: Longest wait (s) for another process's commit of the same output folder.
COMMIT_LOCK_WAIT = 60.0
_STAGING = ".veil-partial-"
_BACKUP = ".veil-replaced-"


def as_path(path, what: str) -> str:
    """``path`` as a string (``os.fspath``) when it is a ``str`` or an ``os.PathLike``; an
    InputTypeError naming ``what`` (the argument) otherwise: None, a number, a table."""
    if isinstance(path, (str, os.PathLike)):
        name = os.fspath(path)
        if isinstance(name, str):
            return name
    raise InputTypeError(
        f"{what} = {_shown(path)}: expected a path (a str or pathlib.Path), got "
        f"{type(path).__name__}"
    )


def _shown(value) -> str:
    """``repr(value)``, cut to 60 characters (a DataFrame's repr runs to many lines)."""
    text = " ".join(repr(value).split())
    return text if len(text) <= 60 else text[:57] + "..."


def _umask_mode(bits: int = 0o666) -> int:
    umask = os.umask(0)
    os.umask(umask)
    return bits & ~umask


def no_directory(directory: str) -> str:
    """Why ``directory``, which is not a directory, cannot hold an output: it does not exist,
    or it (or a folder above it) is a regular file."""
    above = directory
    while above and not os.path.lexists(above) and os.path.dirname(above) != above:
        above = os.path.dirname(above)
    if os.path.lexists(above) and not os.path.isdir(above):
        return f"{above} is a file, not a directory"
    return f"directory {directory} does not exist"


#: Byte-order marks of the encodings a text file that is not UTF-8 most often has (a
#: spreadsheet's or Windows editor's "Unicode text"); the longer ones first.
_BYTE_ORDER_MARKS = (
    (b"\xff\xfe\x00\x00", "UTF-32"),
    (b"\x00\x00\xfe\xff", "UTF-32"),
    (b"\xff\xfe", "UTF-16"),
    (b"\xfe\xff", "UTF-16"),
)


def other_encoding(name, head: bytes | None = None) -> str | None:
    """The message for a file ``name`` that is not UTF-8 but begins (``head``, read from the
    file when not given) with the byte-order mark of UTF-16 or UTF-32: which one, and how to
    save it as UTF-8; None for any other bytes (each reader says its own "not UTF-8")."""
    if head is None:
        try:
            with open(name, "rb") as fh:
                head = fh.read(4)
        except OSError:
            return None
    for mark, encoding in _BYTE_ORDER_MARKS:
        if head.startswith(mark):
            return (
                f"{name} is {encoding} text (it begins with the {encoding} byte-order mark), "
                f"not UTF-8: save it as UTF-8 (a spreadsheet's 'CSV UTF-8', an editor's "
                f"UTF-8 encoding, or iconv -f {encoding} -t UTF-8)"
            )
    return None


def not_a_regular_file(path: str) -> str | None:
    """What ``path`` is when it exists but is neither a regular file nor a directory (``a
    character device``, ``a named pipe (FIFO)``, ...), else None. An output is replaced
    whole by a renamed temporary file, which would put a regular file in place of a device
    such as /dev/null or a pipe another program reads: such a path is refused."""
    try:
        mode = os.stat(path).st_mode
    except (OSError, ValueError):
        return None
    if stat.S_ISREG(mode) or stat.S_ISDIR(mode):
        return None
    kinds = (
        (stat.S_ISCHR, "a character device"),
        (stat.S_ISBLK, "a block device"),
        (stat.S_ISFIFO, "a named pipe (FIFO)"),
        (stat.S_ISSOCK, "a socket"),
    )
    return next((said for test, said in kinds if test(mode)), "not a regular file")


def output_file_problem(path: str) -> str | None:
    """Why ``path`` cannot be an output file, said after "cannot write PATH: ": it ends in
    a separator (a folder's name: it would be written as a file of that name), or it is a
    device, a pipe or a socket (:func:`special_file`); None for a path that may be one."""
    if path.endswith(("/", os.sep)) and not os.path.isdir(path):
        return "the path ends in '/', which names a folder; give a file name"
    return special_file(path)


def special_file(path: str) -> str | None:
    """Why an output ``path`` that :func:`not_a_regular_file` finds cannot be written,
    said after "cannot write PATH: ", or None for a path that may be written."""
    kind = not_a_regular_file(path)
    if kind is None:
        return None
    return (
        f"it is {kind}, not a regular file; veil writes an output as a new file renamed "
        f"over the old one, which would replace it: give the path of a regular file"
    )


def through_link(path: str) -> str:
    """Where an output ``path`` is written: ``path`` itself, or, when it is a symbolic link
    (to a file or a folder, or dangling), what it points to, resolved through every link:
    the link stays and its target gets the new content, written atomically as any output
    (docs/errors.md). :class:`veil.errors.UnwritableError` for a link whose target's
    directory does not exist, and for a loop of links."""
    if not os.path.islink(path):
        return path
    target = os.path.realpath(path)
    if os.path.islink(target):
        raise UnwritableError(f"cannot write {path}: it is a loop of symbolic links")
    directory = os.path.dirname(target)
    if not os.path.isdir(directory):
        raise UnwritableError(
            f"cannot write {path}: it is a symbolic link to {target}, and {no_directory(directory)}"
        )
    return target


def _unwritable(path: str, exc: OSError) -> UnwritableError:
    directory = os.path.dirname(os.path.abspath(path))
    reason = exc.strerror or str(exc)
    if not os.path.isdir(directory):
        return UnwritableError(f"cannot write {path}: {no_directory(directory)}")
    return UnwritableError(f"cannot write {path}: directory {directory} is not writable ({reason})")


def write_error(path, exc: OSError) -> UnwritableError:
    """The error of an output ``path`` that could not be written for a reason of the system
    (no space left on the device, a quota, an I/O error, a read-only filesystem): an
    :class:`veil.errors.UnwritableError` (exit status 2) naming the path and the reason."""
    code = errno.errorcode.get(exc.errno or 0, "")
    reason = exc.strerror or str(exc) or type(exc).__name__
    return UnwritableError(
        f"cannot write {os.fspath(path)}: {reason}"
        + (f" ({code})" if code else "")
        + "; nothing was written there"
    )


def _record(path: str) -> None:
    with COMMIT:
        path = os.path.abspath(path)
        if path in _written:
            _written.remove(path)
        _written.append(path)


def write_bytes_atomic(path, data: bytes) -> None:
    """Write ``data`` to ``path`` so that readers see the old file or the new, never half.

    The temporary file lives in the same directory (same filesystem, so the rename is
    atomic), is synced before the rename and removed if anything fails or the process is
    interrupted. A replaced file keeps its permission bits; a new file gets 0666 minus the
    umask. Raises :class:`veil.errors.UnwritableError` when the directory cannot be written
    or the write fails (no space left on the device, any error of the operating system;
    the target is then as it was) and :class:`veil.errors.NotAFileError` when ``path`` is a
    directory.
    """
    write_many_atomic({path: data})


def _temporary(path: str, data: bytes) -> str:
    """A synced temporary file beside ``path`` holding ``data`` with the mode ``path`` will
    have (registered; removed again if anything fails)."""
    if os.path.isdir(path):
        raise NotAFileError(f"cannot write {path}: it is a directory")
    special = output_file_problem(path)
    if special:
        raise NotAFileError(f"cannot write {path}: {special}")
    directory = os.path.dirname(os.path.abspath(path))
    try:
        mode = os.stat(path).st_mode & 0o7777
    except OSError:
        mode = _umask_mode()
    with COMMIT:  # no temporary is created once an interrupt is being handled
        try:
            fd, tmp = tempfile.mkstemp(
                dir=directory, prefix=f".{os.path.basename(path)}.", suffix=".tmp"
            )
        except OSError as exc:
            if exc.errno in (errno.EACCES, errno.EPERM, errno.ENOENT, errno.ENOTDIR):
                raise _unwritable(path, exc) from None
            raise write_error(path, exc) from None
        _temporaries[tmp] = "file"
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, mode)
    except BaseException as exc:
        _discard([tmp])
        if isinstance(exc, OSError) and not isinstance(exc, UnwritableError):
            raise write_error(path, exc) from None
        raise
    return tmp


def _discard(temps) -> None:
    # under COMMIT: an interrupt being handled (it holds COMMIT until the process exits,
    # having removed the temporaries and the partial folder) ends the process with its
    # status here, not an error of the write it pulled the folder from under
    with COMMIT:
        for tmp in temps:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
            _temporaries.pop(tmp, None)


def write_many_atomic(files: dict) -> None:
    """Write several files ({path: bytes}) together: every one to a synced temporary file
    first, then all renamed into place at once (under :data:`COMMIT`; renames within a
    folder need no space). If any cannot be written (no space left, a read-only folder),
    none is replaced, the temporaries are removed and an
    :class:`veil.errors.UnwritableError` names the path: a command never leaves some of its
    outputs new and others old."""
    given = [os.fspath(p) for p in files]
    paths = [through_link(p) for p in given]  # a link stays; its target is replaced
    temps: list[str] = []
    committed = 0  # the temporaries renamed into place so far
    try:
        for path, data in zip(paths, files.values()):
            temps.append(_temporary(path, data))
        with COMMIT:
            for path, tmp in zip(paths, temps):
                try:
                    os.replace(tmp, path)
                except OSError as exc:
                    raise write_error(path, exc) from None
                _temporaries.pop(tmp, None)
                committed += 1
                _record(given[committed - 1])
    except BaseException:
        _discard(temps[committed:])
        raise


def write_text_atomic(path, text: str) -> None:
    """:func:`write_bytes_atomic` of ``text`` encoded as UTF-8 (newlines as given)."""
    write_bytes_atomic(path, text.encode("utf-8"))


def check_output_folder(path) -> str:
    """The absolute path of an output folder that can be written (created if missing), or
    :class:`veil.errors.UnwritableError` saying why not."""
    path = through_link(os.path.abspath(os.fspath(path)))  # a link stays, written through
    if os.path.exists(path):
        if not os.path.isdir(path):
            raise UnwritableError(f"output directory {path} exists and is not a directory")
        if not os.access(path, os.W_OK | os.X_OK):
            raise UnwritableError(f"output directory {path} is not writable")
        return path
    parent = os.path.dirname(path)
    if not os.path.isdir(parent):
        raise UnwritableError(f"cannot create the output directory {path}: {no_directory(parent)}")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise UnwritableError(
            f"cannot create the output directory {path}: directory {parent} is not writable"
        )
    return path


def _make_staging(path: str, existed: bool) -> str:
    """A temporary folder on the same filesystem as ``path``: inside it when it exists (its
    entries are then renamed one by one), beside it otherwise (renamed as a whole)."""
    where, prefix = (
        (path, _STAGING)
        if existed
        else (os.path.dirname(path), f".{os.path.basename(path)}{_STAGING}")
    )
    with COMMIT:
        try:
            staging = tempfile.mkdtemp(dir=where, prefix=prefix)
        except OSError as exc:
            raise UnwritableError(
                f"cannot write into the output directory {path} ({exc.strerror or exc})"
            ) from None
        _temporaries[staging] = "folder"
    os.chmod(staging, _umask_mode(0o777))
    return staging


def _merge(staging: str, path: str, owned) -> str:
    """Move every entry of ``staging`` into ``path`` (replacing entries of the same name)
    and move the ``owned`` names this run did not write out of it. Returns the folder
    holding what was replaced (to delete); on error puts everything back and raises."""
    backup = tempfile.mkdtemp(dir=path, prefix=_BACKUP)
    new = sorted(os.listdir(staging))
    stale = sorted(set(owned or ()) - set(new))
    done: list[tuple[str, bool | None]] = []  # (name, whether an old entry was moved)
    try:
        for name in new:
            target = os.path.join(path, name)
            had = os.path.lexists(target)
            if had:
                os.rename(target, os.path.join(backup, name))
            done.append((name, had))
            os.rename(os.path.join(staging, name), target)
        for name in stale:
            target = os.path.join(path, name)
            if os.path.lexists(target):
                os.rename(target, os.path.join(backup, name))
                done.append((name, None))
    except BaseException:
        for name, moved in reversed(done):
            target = os.path.join(path, name)
            with contextlib.suppress(OSError):
                if moved is not None:
                    if os.path.lexists(target):
                        os.rename(target, os.path.join(staging, name))
                if moved is not False:
                    os.rename(os.path.join(backup, name), target)
        with contextlib.suppress(OSError):
            os.rmdir(backup)
        raise
    return backup


@contextlib.contextmanager
def _commit_lock(path: str):
    """Held while a folder is moved into place, so that two processes writing the same
    folder at once commit one after the other (the last one's files win, whole) instead of
    interleaving their entries. A file lock (:mod:`filelock`) in the temporary directory,
    named after the folder's path: nothing is added beside or inside the folder."""
    from filelock import FileLock, Timeout

    where = os.path.join(tempfile.gettempdir(), "veil-locks")
    try:
        os.makedirs(where, exist_ok=True)
        lock = FileLock(
            os.path.join(where, hashlib.sha256(path.encode()).hexdigest()[:32] + ".lock"),
            timeout=COMMIT_LOCK_WAIT,
        )
        lock.acquire()
    except Timeout:
        raise UnwritableError(
            f"cannot write {path}: another process has been moving its "
            f"files into it for {COMMIT_LOCK_WAIT:g} s"
        ) from None
    except OSError:  # no usable temporary directory: commit unlocked, as before
        yield
        return
    try:
        yield
    finally:
        lock.release()


def _commit(staging: str, path: str, owned):
    """Move ``staging`` into place as ``path`` (renamed whole when ``path`` does not exist,
    merged entry by entry otherwise); returns the folder of replaced entries, or None."""
    if not os.path.isdir(path):
        try:
            os.rename(staging, path)
            return None
        except OSError as exc:  # another process's folder appeared meanwhile: merge
            if exc.errno not in (errno.ENOTEMPTY, errno.EEXIST) or not os.path.isdir(path):
                raise
    backup = _merge(staging, path, owned)
    os.rmdir(staging)
    return backup


@contextlib.contextmanager
def output_folder(path, owned=None) -> Iterator[Path]:
    """Write a folder of outputs as one transaction; yields the folder to write into.

    Everything is written into a temporary folder (a hidden sibling when ``path`` does not
    exist yet, a hidden subfolder otherwise) and moved into ``path`` when the block ends
    without an exception: the whole folder is renamed into place, or, into an existing
    folder, each new entry replaces the entry of the same name, and entries named in
    ``owned`` that this run did not write (left from an earlier run with other options) are
    removed. Other entries of an existing folder are left alone. The moves happen while
    holding :data:`COMMIT`, so an interrupt handled by the command line lands before them
    or after them. If the block raises (or the process is interrupted), the temporary folder
    is deleted and ``path`` is as it was: the earlier complete result, or nothing.

    Raises :class:`veil.errors.UnwritableError` if ``path`` cannot be created or written.
    """
    path = check_output_folder(path)
    existed = os.path.isdir(path)
    staging = _make_staging(path, existed)
    outer = _folders.get(path)
    _folders[path] = existed if outer is None else outer
    try:
        yield Path(staging)
        with COMMIT, _commit_lock(path):
            backup = _commit(staging, path, owned)
            _temporaries.pop(staging, None)
            if backup is not None:
                _temporaries[backup] = "folder"
            prefix = staging + os.sep  # what was recorded inside the staging folder moved
            _written[:] = [w for w in _written if w != staging and not w.startswith(prefix)]
            _record(path)
        if backup is not None:
            shutil.rmtree(backup, ignore_errors=True)
            _temporaries.pop(backup, None)
    finally:
        if _temporaries.pop(staging, None) is not None:
            shutil.rmtree(staging, ignore_errors=True)
        if outer is None:
            _folders.pop(path, None)


# --------------------------------------------------------------------------------------
# what an interrupted process leaves behind (called by veil.cli.interrupts)
# --------------------------------------------------------------------------------------
def register_temporary(path, kind: str = "folder") -> None:
    """Have an interrupted command line remove ``path`` (a "folder" or a "file")."""
    with COMMIT:
        _temporaries[os.path.abspath(os.fspath(path))] = kind


def forget_temporary(path) -> None:
    """Undo :func:`register_temporary`."""
    with COMMIT:
        _temporaries.pop(os.path.abspath(os.fspath(path)), None)


def register_partial(path, note: str) -> None:
    """Say, if the command line is interrupted, that ``path`` is kept partial and ``note``
    (what it is and how to finish it: a maps store resumes)."""
    with COMMIT:
        _partial[os.path.abspath(os.fspath(path))] = note


def forget_partial(path) -> None:
    """Undo :func:`register_partial`."""
    with COMMIT:
        _partial.pop(os.path.abspath(os.fspath(path)), None)


def written() -> list[str]:
    """Complete outputs this process has written so far (files and folders, absolute
    paths), leaving out those inside temporaries that will be removed."""
    temps = [t + os.sep for t, kind in _temporaries.items() if kind == "folder"]
    return [w for w in _written if os.path.lexists(w) and not any(w.startswith(t) for t in temps)]


def abandon() -> str:
    """Remove every registered temporary and say what is left, as a sentence fragment
    ("nothing was written", "complete: a.png, b.json", "results/ is as it was").

    For the interrupt handler, which calls it holding :data:`COMMIT`, just before the
    process exits; the process must not write anything afterwards.
    """
    done = written()
    temps = [t + os.sep for t, kind in _temporaries.items() if kind == "folder"]
    kept = [
        p for p, existed in _folders.items() if existed and not any(p.startswith(t) for t in temps)
    ]
    for tmp, kind in list(_temporaries.items()):
        with contextlib.suppress(OSError):
            if kind == "folder":
                shutil.rmtree(tmp, ignore_errors=True)
            else:
                os.unlink(tmp)
    _temporaries.clear()
    cwd = os.getcwd() if os.path.isdir(os.curdir) else None

    def show(p):
        rel = os.path.relpath(p, cwd) if cwd else p
        name = rel if not rel.startswith(os.pardir) else p
        return name + (os.sep if os.path.isdir(p) else "")

    parts = []
    if done:
        names = [show(p) for p in done]
        more = f" and {len(names) - 4} more" if len(names) > 5 else ""
        parts.append("complete: " + ", ".join(names[:4] if more else names) + more)
    elif not _partial:
        parts.append("nothing was written")
    parts += [f"{show(p)} is {note}" for p, note in _partial.items() if os.path.isdir(p)]
    kept = [p for p in kept if not any(p == d or p.startswith(d + os.sep) for d in done)]
    if kept:
        parts.append(
            ", ".join(show(p) for p in kept)
            + (" is" if len(kept) == 1 else " are")
            + " as the earlier run left "
            + ("it" if len(kept) == 1 else "them")
        )
    return "; ".join(parts)


__all__ = [
    "as_path",
    "write_bytes_atomic",
    "write_text_atomic",
    "write_many_atomic",
    "write_error",
    "output_folder",
    "check_output_folder",
    "through_link",
    "COMMIT",
    "written",
    "abandon",
    "register_temporary",
    "forget_temporary",
    "register_partial",
    "forget_partial",
]
