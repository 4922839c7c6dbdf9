"""The on-disk cache of generated model modules: where it is, keys, store and load.

A symbolic model's kernels are written as a Python module ``m_<key>.py`` in the cache
folder, ``<key>`` a hash of the model's expressions (:func:`model_key`); numba caches the
compiled kernels of that file next to it (``__pycache__``), so a second process neither
re-derives nor recompiles. The folder is ``$BDERIV_CACHE_DIR/symbolic`` when that variable
is set, else ``$NUMBA_CACHE_DIR/bderiv/symbolic`` when numba's is, else
``$XDG_CACHE_HOME/bderiv/symbolic`` (default ``~/.cache/bderiv/symbolic``).
A file is never rewritten: a model whose expressions change gets a new key. Deleting the
folder is always safe.

Damage. A module's first line is the sha256 of the rest (:func:`store`), checked by
:func:`read` before the module is run: a damaged file (a flipped bit may still parse, and
compute another model) is removed, with a warning naming it, and generated again; a file
without that line (an older bderiv's) is generated again too. The module is run from the
checked text (:func:`load`), so no ``.pyc`` of it is written or read; numba's cache of its
kernels is bderiv's checked one (:func:`bderiv.symbolic._model.compile_kernels`).
"""

from __future__ import annotations

import hashlib
import logging
import os
import pathlib
import sys
import tempfile
import types

#: environment variable that overrides the cache folder
CACHE_ENV = "BDERIV_CACHE_DIR"
#: how a generated module's first line starts: the sha256 (hex) of the rest follows
DIGEST_LINE = "# bderiv sha256 "

log = logging.getLogger("bderiv")


def cache_folder(cache_dir=None) -> pathlib.Path:
    """The folder of the generated modules (created if missing).

    Parameters
    ----------
    cache_dir : str or os.PathLike, optional
        Root folder; default ``$BDERIV_CACHE_DIR``, else ``$NUMBA_CACHE_DIR/bderiv`` (the
        compiled kernels' cache the user chose), else ``$XDG_CACHE_HOME/bderiv``, else
        ``~/.cache/bderiv``.

    Returns
    -------
    pathlib.Path
        ``<root>/symbolic``.
    """
    if cache_dir is None:
        cache_dir = os.environ.get(CACHE_ENV) or None
    if cache_dir is None and os.environ.get("NUMBA_CACHE_DIR"):
        cache_dir = pathlib.Path(os.environ["NUMBA_CACHE_DIR"]) / "bderiv"
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
    """Write ``source`` to ``path`` atomically, led by its digest line, unless it is there.

    A concurrent reader sees all or nothing, and a file written meanwhile by another
    process (the same source: same key) is kept, so numba's cache of it stays valid (it
    is keyed by the file's modification time).
    """
    digest = hashlib.sha256(source.encode("utf-8")).hexdigest()
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".tmp_", suffix=".py")
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="") as f:
            f.write(f"{DIGEST_LINE}{digest}\n{source}")
        try:
            os.link(tmp, path)  # fails if the file exists: the first writer wins
        except FileExistsError:
            pass
        except OSError:  # no hard links on this file system
            os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def read(path: pathlib.Path) -> str | None:
    """The source stored at ``path`` (without its digest line), or None: no file, or one
    that fails its digest (removed, with a warning naming it) or has none (removed)."""
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        return None
    head, _, body = data.partition(b"\n")
    text = head.decode("ascii", "replace")
    if not text.startswith(DIGEST_LINE):
        log.debug("bderiv: %s has no digest line (an older bderiv's): generated again", path)
    elif hashlib.sha256(body).hexdigest() == text[len(DIGEST_LINE):]:
        return body.decode("utf-8")  # the text store wrote
    else:
        log.warning("bderiv: the generated model module %s is damaged (its content does not "
                    "match the sha256 digest it was written with): removed and generated "
                    "again. If this repeats, check the disk or delete the folder %s",
                    path, path.parent)
    path.unlink(missing_ok=True)
    return None


def load(path: pathlib.Path, key: str, source: str):
    """Run ``source`` (the checked text of the module at ``path``, :func:`read`) as the
    module of ``key``, once per process: later calls reuse it.

    Running it defines the kernels; they are compiled (or loaded from the cache next to
    the file) by :func:`bderiv.symbolic._model.compile_kernels`.
    """
    name = f"bderiv_symbolic_{key}"
    if name in sys.modules:
        return sys.modules[name]
    module = types.ModuleType(name)
    module.__file__ = str(path)  # numba's cache sits next to the file, stamped by it
    sys.modules[name] = module  # before running it, as an import does: numba's cache
    try:  # of corner_field refers to field through the module's name
        exec(compile(source, str(path), "exec"), module.__dict__)
    except BaseException:
        del sys.modules[name]
        raise
    return module
