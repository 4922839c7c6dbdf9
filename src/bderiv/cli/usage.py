"""Usage errors: the checks of the user's arguments that argparse cannot make.

A :class:`UsageError` is the only exception the command line reports as a bad argument
(one line on stderr, exit status 2); anything else that goes wrong is a bug or a failure of
the machine and keeps its traceback.
"""

from __future__ import annotations

import importlib.util
import os
import tempfile

from .._support._tables import human_bytes, memory_headroom

#: the extra of ``pip install 'bderiv[...]'`` that brings each optional module
EXTRAS = {"matplotlib": "plot"}


class UsageError(Exception):
    """A bad argument found after parsing; reported in one line, exit status 2."""


def require_memory(nbytes: int, what: str) -> None:
    """Refuse ``what`` when it needs more than the process may take now (the memory
    available, and under ``ulimit -v`` what the address-space limit leaves).

    Parameters
    ----------
    nbytes : int
        Estimated peak bytes (Python ints: no overflow for any size asked for).
    what : str
        The allocation in the user's words, e.g. ``"--batch 1000000000000 (d = 6)"``.

    Examples
    --------
    >>> require_memory(1 << 60, "--n 60")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    bderiv.cli.usage.UsageError: --n 60 needs about 1024.0 PiB of memory, but only ...
    """
    free = memory_headroom()
    if nbytes > free:
        raise UsageError(
            f"{what} needs about {human_bytes(nbytes)} of memory, but only "
            f"{human_bytes(free)} is available; ask for less"
        )


def require_demo_memory(batch: int, check: int, dim: int) -> None:
    """Refuse a demo whose batch (with its image and one temporary of the flow's stages) or
    check vectors do not fit, ``3 * vectors * dim`` float64 each."""
    require_memory(3 * batch * dim * 8, f"--batch {batch} (d = {dim})")
    require_memory(3 * check * dim * 8, f"--check {check} (d = {dim})")


def require_module(module: str, for_what: str) -> None:
    """Refuse ``for_what`` when the optional ``module`` is not installed."""
    if importlib.util.find_spec(module) is None:
        raise UsageError(
            f"{for_what} needs {module}: pip install 'bderiv[{EXTRAS.get(module, module)}]'"
        )


def require_robot_files(for_what: str) -> None:
    """Refuse ``for_what`` without Pinocchio or example-robot-data (the extra ``robots``)."""
    from ..robots import _files

    try:
        _files.require_pinocchio()
        _files.example_robot_data()
    except ImportError as exc:  # the library's message says what to install
        raise UsageError(f"{for_what}: {exc}") from None


def check_figure_path(path: str, option: str) -> None:
    """Refuse a figure path before any work is done (suffix; a directory that exists and
    is writable, or can be made; no directory of that name in the way)."""
    if not path.lower().endswith((".png", ".pdf", ".svg")):  # ".png" too: a hidden file
        raise UsageError(f"{option}: figure file {path!r} must end in .png, .pdf or .svg")
    check_output_directory(os.path.dirname(os.path.abspath(path)), option)
    check_output_file(path, option)


def check_output_file(path: str, option: str, in_place: bool = True) -> None:
    """Refuse, before any work is done, an output file that exists but cannot be replaced:
    a directory of that name, or (``in_place``: a file opened for writing, not replaced by
    a rename) a file that this process may not write.

    Examples
    --------
    >>> import tempfile
    >>> check_output_file(tempfile.mkdtemp(), "--out")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    bderiv.cli.usage.UsageError: --out: cannot write '...': a directory of that name is in the way
    """
    if os.path.isdir(path):
        raise UsageError(f"{option}: cannot write {path!r}: a directory of that name is in "
                         f"the way")
    if in_place and os.path.exists(path) and not os.access(path, os.W_OK):
        raise UsageError(f"{option}: cannot write {path!r}: the file there is not writable")


def check_output_directory(directory: str, option: str) -> None:
    """Refuse, before any work is done, an output directory that cannot be written.

    Every command that writes files makes a missing output directory, with its missing
    parents (:func:`make_output_directory`, once the work is done). So a directory that
    exists must take a file, and a missing one must have a writable directory as its
    nearest existing ancestor. Writability is tried by creating (and removing) a temporary
    file, so that read-only mounts and pseudo file systems such as ``/proc`` are refused.

    Examples
    --------
    >>> import os, tempfile
    >>> blocker = os.path.join(tempfile.mkdtemp(), "file")
    >>> open(blocker, "w").close()
    >>> check_output_directory(os.path.join(blocker, "figs"), "--out")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    bderiv.cli.usage.UsageError: --out: cannot make the directory ...: ... not a directory)
    """
    target = os.path.abspath(directory)
    ancestor = target
    while not os.path.exists(ancestor):
        ancestor = os.path.dirname(ancestor)
    if not os.path.isdir(ancestor):
        raise UsageError(f"{option}: cannot make the directory {directory!r}: the location is "
                         f"not writable ({ancestor!r} is a file, not a directory)")
    try:
        with tempfile.TemporaryFile(dir=ancestor):
            pass
    except OSError as exc:
        made = "" if ancestor == target else f"cannot make the directory {directory!r}: "
        raise UsageError(
            f"{option}: {made}output directory {ancestor!r} is not writable (creating a "
            f"file there failed: {exc.strerror or exc})"
        ) from None


def make_output_directory(directory: str, option: str) -> str | None:
    """Make ``directory`` and its missing parents; return the topmost directory made (to
    say so in the command's output), or None when it existed.

    Examples
    --------
    >>> import os, tempfile
    >>> root = tempfile.mkdtemp()
    >>> made = make_output_directory(os.path.join(root, "a", "b"), "--out")
    >>> made == os.path.join(root, "a"), make_output_directory(made, "--out")
    (True, None)
    """
    target = os.path.abspath(directory)
    top = None
    while not os.path.exists(target):
        top, target = target, os.path.dirname(target)
    if top is None:
        return None
    try:
        os.makedirs(directory, exist_ok=True)
    except OSError as exc:
        raise UsageError(f"{option}: cannot make the directory {directory!r}: the location is "
                         f"not writable ({exc.strerror or exc})") from None
    return top


def not_writable(option: str, path: str, exc: OSError) -> str:
    """The message of a file that could not be written: its directory is not writable."""
    return (f"{option}: cannot write {path!r}: the location is not writable (the system "
            f"answered: {exc.strerror or exc})")
