"""The on-disk cache of generated model modules: where it is, keys, store and load.

A symbolic model's kernels are written as a Python module ``m_<key>.py`` in the cache
folder, ``<key>`` a hash of the model's expressions (:func:`model_key`); numba caches the
compiled kernels of that file next to it (``__pycache__``), so a second process neither
re-derives nor recompiles. The folder is ``$BDERIV_CACHE_DIR/symbolic`` when that variable
is set, else ``$XDG_CACHE_HOME/bderiv/symbolic`` (default ``~/.cache/bderiv/symbolic``).
A file is never rewritten: a model whose expressions change gets a new key. Deleting the
folder is always safe.
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
import pathlib
import sys
import tempfile

#: environment variable that overrides the cache folder
CACHE_ENV = "BDERIV_CACHE_DIR"


def cache_folder(cache_dir=None) -> pathlib.Path:
    """The folder of the generated modules (created if missing).

    Parameters
    ----------
    cache_dir : str or os.PathLike, optional
        Root folder; default ``$BDERIV_CACHE_DIR``, else ``$XDG_CACHE_HOME/bderiv``, else
        ``~/.cache/bderiv``.

    Returns
    -------
    pathlib.Path
        ``<root>/symbolic``.
    """
    if cache_dir is None:
        cache_dir = os.environ.get(CACHE_ENV) or None
    if cache_dir is None:
        base = os.environ.get("XDG_CACHE_HOME") or pathlib.Path.home() / ".cache"
        cache_dir = pathlib.Path(base) / "bderiv"
    if not isinstance(cache_dir, str | os.PathLike):
        raise TypeError(f"cache_dir must be a path (str or os.PathLike), got "
                        f"{type(cache_dir).__name__}")
    folder = pathlib.Path(cache_dir) / "symbolic"
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OSError(f"cannot create the cache folder of symbolic models {folder}: {exc}; "
                      f"set {CACHE_ENV} or pass cache_dir= a writable folder") from None
    return folder


def model_key(parts) -> str:
    """A 24-hex-digit hash of the strings ``parts`` (the model's canonical description)."""
    h = hashlib.sha256()
    for part in parts:
        h.update(part.encode("utf-8"))
        h.update(b"\0")
    return h.hexdigest()[:24]


def module_path(folder: pathlib.Path, key: str) -> pathlib.Path:
    """The path of the generated module of ``key`` in ``folder``."""
    return folder / f"m_{key}.py"


def store(path: pathlib.Path, source: str) -> None:
    """Write ``source`` to ``path`` atomically, unless it is there already.

    A concurrent reader sees all or nothing, and a file written meanwhile by another
    process (the same source: same key) is kept, so numba's cache of it stays valid (it
    is keyed by the file's modification time).
    """
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".tmp_", suffix=".py")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(source)
        try:
            os.link(tmp, path)  # fails if the file exists: the first writer wins
        except FileExistsError:
            pass
        except OSError:  # no hard links on this file system
            os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def load(path: pathlib.Path, key: str):
    """Import the generated module at ``path`` (once per process: later calls reuse it).

    Importing defines the kernels; they are compiled (or loaded from the cache next to
    the file) by :func:`bderiv.symbolic._model.compile_kernels`.
    """
    name = f"bderiv_symbolic_{key}"
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # before running it, as an import does: numba's cache
    try:  # of corner_field refers to field through the module's name
        spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[name]
        raise
    return module
