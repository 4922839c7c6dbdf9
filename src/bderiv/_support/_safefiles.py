"""Files read and written safely: regular files only, bounded reads, all-or-none writes.

Nothing in the standard library writes several files all or none or refuses a device
before reading it, so these few functions do: :func:`read_regular` reads a regular file
whose size the memory limit allows (``/dev/zero``, a FIFO or a folder is refused, checked
on the open descriptor); :func:`write_all` writes every file to a temporary file beside
its target, syncs it, and replaces the targets with ``os.replace`` only when all are
written. Used by the triangulation files (:mod:`bderiv.geometry._triangulation_io`).

A process killed while it writes leaves its temporary file
(``.NAME.<pid>-<host>.<random>.tmp``, hidden, beside the target); the next write of the
same target removes it (:func:`remove_stale_temps`): a temporary of that target whose
process (pid, on this host) is gone, or, where that cannot be told (another host, a name
without a pid), whose file is older than :data:`STALE_SECONDS`. A concurrent writer's
live temporary is never removed.
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import secrets
import socket
import stat
import time

from ._validate import check_memory

#: age (seconds) after which a temporary whose writer cannot be checked is stale: a day
STALE_SECONDS = 86400
#: the tail of a temporary's name after ``.NAME.``: ``<pid>-<host>.<random>.tmp``, or
#: ``<random>.tmp`` as bderiv wrote it before the pid was in the name
_TEMP_TAIL = re.compile(r"(?:(\d+)-([A-Za-z0-9-]*)\.)?[0-9a-f]{16}\.tmp")


def read_regular(path: str, source: str, memory_limit, per_byte: int = 1,
                  how: str = "") -> bytes:
    """The bytes of ``path``, a regular file whose size times ``per_byte`` (the least
    memory a byte of it takes once read and ``how``) fits in the memory limit."""
    with open_regular(path, source) as fh:
        size = os.fstat(fh.fileno()).st_size
        check_memory(per_byte * size, memory_limit,
                     f"reading {source} ({size} bytes{how}: {per_byte} bytes a byte at least)")
        text = fh.read(size + 1)
    if len(text) != size:
        raise ValueError(f"{source} changed size while it was read ({size} bytes expected, "
                         f"{len(text)}{'+' if len(text) > size else ''} read)")
    return text


def open_regular(path: str, source: str):
    """``path`` opened for binary reading, refused unless it is a regular file.

    Opened without blocking (a FIFO would wait for a writer) and checked on the open
    descriptor, so that nothing can swap the file between the check and the read.
    """
    fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_BINARY", 0))
    mode = os.fstat(fd).st_mode
    if not stat.S_ISREG(mode):
        os.close(fd)
        kind = ("a directory" if stat.S_ISDIR(mode) else "a device" if stat.S_ISCHR(mode)
                or stat.S_ISBLK(mode) else "a pipe" if stat.S_ISFIFO(mode) else
                "a socket" if stat.S_ISSOCK(mode) else "not a regular file")
        raise ValueError(f"{source} must be a regular file, got {kind}")
    return os.fdopen(fd, "rb")


def write_all(targets: dict, check=None) -> None:
    """Write several files, all or none.

    Parameters
    ----------
    targets : dict
        ``{path: (binary, write)}``: ``write(fh)`` writes the file's content to ``fh``,
        opened for bytes when ``binary``, else for UTF-8 text.
    check : callable, optional
        ``check({path: temporary path})``, called when every file is written and synced,
        before any target is replaced (to read them back): if it raises, nothing is
        replaced.

    Notes
    -----
    Each file is written to a temporary file beside its target
    (``.NAME.<pid>-<host>.<random>.tmp``, with the target's permissions when it exists),
    flushed and ``fsync``-ed; only then are
    the targets replaced with ``os.replace``, which is atomic for each file, and the folders
    synced. Any failure before that (a full disk, an exception, Ctrl-C) removes the
    temporaries and leaves every target as it was; a process killed outright may leave a
    temporary file, never a damaged target (the next write of that target removes it:
    :func:`remove_stale_temps`). Between the replacements of two files there is no
    writing, only renames.
    """
    temps = {}
    for path in targets:
        remove_stale_temps(path)
    try:
        for path, (binary, write) in targets.items():
            temps[path], fd = create_temp(path)
            with os.fdopen(fd, "wb") if binary else os.fdopen(fd, "w", encoding="utf-8") as fh:
                write(fh)
                fh.flush()
                os.fsync(fh.fileno())
        if check is not None:
            check(dict(temps))
        for path, temp in temps.items():
            os.replace(temp, path)
    except BaseException:
        for temp in temps.values():
            with contextlib.suppress(FileNotFoundError):
                os.unlink(temp)
        raise
    for folder in {os.path.dirname(os.path.abspath(path)) for path in targets}:
        sync_folder(folder)


def text_path(path, name: str = "path") -> str:
    """``path`` (a str or an ``os.PathLike``) as a str; bytes and others refused by name."""
    try:
        out = os.fspath(path)
    except TypeError:
        out = path
    if not isinstance(out, str):
        raise TypeError(f"{name} must be a str or an os.PathLike of a str, got "
                        f"{type(path).__name__} {path!r}")
    return out


def create_temp(path: str) -> tuple[str, int]:
    """A new temporary file beside ``path`` (same folder: ``os.replace`` stays atomic)."""
    folder, name = os.path.split(os.path.abspath(path))
    if os.path.isdir(path):
        raise IsADirectoryError(errno.EISDIR, "is a directory", path)
    if not os.path.isdir(folder):  # named, not the temporary file that could not be made
        raise FileNotFoundError(errno.ENOENT, f"its folder {folder!r} does not exist", path)
    temp = os.path.join(folder, f".{name}.{os.getpid()}-{_host()}.{secrets.token_hex(8)}.tmp")
    fd = os.open(temp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0),
                 0o666)
    with contextlib.suppress(OSError):  # keep the permissions of the file it replaces
        os.chmod(temp, stat.S_IMODE(os.stat(path).st_mode))
    return temp, fd


def remove_stale_temps(path: str) -> list[str]:
    """Remove the temporary files a killed write of ``path`` left beside it; return them.

    Only ``path``'s own temporaries (``.NAME.<pid>-<host>.<random>.tmp``), and only stale
    ones: written on this host by a process that no longer runs, or, where that cannot be
    told (another host's, Windows, a name without a pid), last modified more than
    :data:`STALE_SECONDS` ago. A concurrent writer's temporary stays.
    """
    folder, name = os.path.split(os.path.abspath(path))
    prefix, removed = f".{name}.", []
    try:
        entries = [e for e in os.scandir(folder) if e.name.startswith(prefix)]
    except OSError:  # no folder yet (the write reports it), or unreadable
        return removed
    for entry in entries:
        tail = _TEMP_TAIL.fullmatch(entry.name[len(prefix):])
        if tail is None or not entry.is_file(follow_symlinks=False):
            continue
        pid, host = tail.groups()
        stale = False
        if pid is not None and host == _host() and os.name == "posix":
            stale = not _running(int(pid))
        else:
            with contextlib.suppress(OSError):
                stale = time.time() - entry.stat(follow_symlinks=False).st_mtime > STALE_SECONDS
        if stale:
            with contextlib.suppress(OSError):
                os.unlink(entry.path)
                removed.append(entry.path)
    return removed


def _host() -> str:
    """This host's name as a temporary's name holds it (letters, digits and ``-``)."""
    return re.sub(r"[^A-Za-z0-9-]", "-", socket.gethostname())[:40]


def _running(pid: int) -> bool:
    """Whether process ``pid`` runs on this host (POSIX: signal 0 checks, sends nothing)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # PermissionError: another user's process
        return True
    return True


def sync_folder(folder: str) -> None:
    """Make the renames in ``folder`` durable (POSIX; a no-op where folders cannot be
    opened)."""
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
