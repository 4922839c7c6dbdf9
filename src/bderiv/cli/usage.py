"""Usage errors: the checks of the user's arguments that argparse cannot make.

A :class:`UsageError` is the only exception the command line reports as a bad argument
(one line on stderr, exit status 2); anything else that goes wrong is a bug or a failure of
the machine and keeps its traceback.
"""

from __future__ import annotations

import importlib.util
import os
import tempfile

from .._tables import available_memory, human_bytes

#: the extra of ``pip install 'bderiv[...]'`` that brings each optional module
EXTRAS = {"matplotlib": "plot"}


class UsageError(Exception):
    """A bad argument found after parsing; reported in one line, exit status 2."""


def require_memory(nbytes: int, what: str) -> None:
    """Refuse ``what`` when it needs more than the memory available now.

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
    free = available_memory()
    if nbytes > free:
        raise UsageError(
            f"{what} needs about {human_bytes(nbytes)} of memory, but only "
            f"{human_bytes(free)} is available; ask for less"
        )


def require_module(module: str, for_what: str) -> None:
    """Refuse ``for_what`` when the optional ``module`` is not installed."""
    if importlib.util.find_spec(module) is None:
        raise UsageError(
            f"{for_what} needs {module}: pip install 'bderiv[{EXTRAS.get(module, module)}]'"
        )


def check_figure_path(path: str, option: str) -> None:
    """Refuse a figure path before any work is done (suffix, writable directory)."""
    ext = os.path.splitext(path)[1].lower()
    if ext not in (".png", ".pdf", ".svg"):
        raise UsageError(f"{option}: figure file {path!r} must end in .png, .pdf or .svg")
    check_writable_directory(os.path.dirname(os.path.abspath(path)), option)


def check_writable_directory(directory: str, option: str) -> None:
    """Refuse an output directory that does not exist or where no file can be created.

    Tried by creating (and removing) a temporary file, so that read-only mounts and
    pseudo file systems such as ``/proc`` are refused before any work is done.
    """
    if not os.path.isdir(directory):
        raise UsageError(f"{option}: output directory {directory!r} does not exist")
    try:
        with tempfile.TemporaryFile(dir=directory):
            pass
    except OSError as exc:
        raise UsageError(
            f"{option}: output directory {directory!r} is not writable (creating a file "
            f"there failed: {exc.strerror or exc})"
        ) from None


def not_writable(option: str, path: str, exc: OSError) -> str:
    """The message of a file that could not be written: its directory is not writable."""
    return (f"{option}: cannot write {path!r}: the location is not writable (the system "
            f"answered: {exc.strerror or exc})")
