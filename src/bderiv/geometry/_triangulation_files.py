"""The files of a :class:`~bderiv.geometry.triangulation.Triangulation`: what they hold,
saved all or none and loaded back checked (``TriangulationFiles``, a mix-in of the class;
:func:`save_files`, several files at once).

The formats themselves (JSON and ``.npz``, the digests, the pair tokens, reads bounded by
the memory limit, writes all or none) are ``_triangulation_io``'s; the fields a file holds
are checked by ``_triangulation_fields`` as the constructor's are.
"""

from __future__ import annotations

import uuid

import numpy as np

from .._support._safefiles import text_path
from ._triangulation_io import (
    FILE_FORMAT,
    PAIR,
    VERSION_FIELDS,
    check_data,
    check_pair,
    file_format,
    read_json,
    read_npz,
    write_files,
)

__all__ = ["TriangulationFiles", "save_files"]


class TriangulationFiles:
    """``to_dict``, ``from_dict``, ``save`` and ``load`` of a ``Triangulation`` (the class
    this mix-in is part of: the annotations name it, F821)."""

    def to_dict(self) -> dict:
        """Plain-Python description (lists of floats and ints), as written to JSON.

        Returns
        -------
        dict
            Keys ``format``, ``version``, ``n_events``, ``dim`` and the arrays ``pre``
            (n_vertices, d), ``post`` (n_vertices, d), ``simplices`` (n_simplices, n + 1)
            and ``kernel`` (d, d - n) as nested lists; version 2 (a map that is not the
            identity on the kernel) also ``kernel_post`` (d, d - n). A saved file holds
            these and the digest ``sha256`` of them.
        """
        header, arrays = self._file_contents()
        return {**header, **{name: arr.tolist() for name, arr in arrays.items()}}

    def _file_version(self) -> int:
        """1 when the map is the identity on the kernel (readable by older bderiv), else 2."""
        return 1 if np.array_equal(self.kernel, self.kernel_post) else 2

    @classmethod
    def from_dict(cls, data: dict, source: str = "triangulation data") -> Triangulation:  # noqa: F821
        """Rebuild from :meth:`to_dict` output, checked completely.

        Parameters
        ----------
        data : dict
            As written by :meth:`to_dict` (the arrays as nested lists or ndarrays).
        source : str
            What ``data`` came from, named in error messages (a file, when loading).

        Raises
        ------
        ValueError
            On a wrong format tag or version, a missing field, a value of the wrong type,
            shape or range, or a degenerate simplex; the message names ``source`` and the
            field.
        """
        fields = check_data(data, source)
        tri = cls.__new__(cls)
        tri._set(fields)
        return tri

    def save(self, path, format: str | None = None) -> str:
        """Write the triangulation to ``path`` as ``.npz`` (binary) or ``.json`` (text).

        Parameters
        ----------
        path : str or os.PathLike
            Destination; its suffix picks the format unless ``format`` is given.
        format : {"npz", "json"}, optional

        Returns
        -------
        str
            The path written.

        Notes
        -----
        Both formats round-trip exactly (JSON writes floats with all their digits). The
        ``.npz`` holds the arrays ``pre``, ``post``, ``simplices``, ``kernel`` and a JSON
        header ``meta``; it loads with ``numpy.load(path)`` alone. Both carry a sha256
        digest of their content (field ``sha256``), which :meth:`load` checks.

        The save is atomic: the file is written to a temporary file in the same folder,
        synced, and then replaces ``path``; a failure midway (a full disk, an exception,
        a kill) leaves a previous file at ``path`` intact.
        """
        path = text_path(path)
        save_files(self, {path: file_format(path, format)})
        return path

    def _file_contents(self) -> tuple[dict, dict]:
        """The header (format, version, sizes) and the arrays a file of this map holds."""
        version = self._file_version()
        header = {"format": FILE_FORMAT, "version": version, "n_events": self.n_events,
                  "dim": self.dim}
        return header, {name: getattr(self, name) for name in VERSION_FIELDS[version]}

    @classmethod
    def load(cls, path, format: str | None = None, *, memory_limit=None) -> Triangulation:  # noqa: F821
        """Read a triangulation written by :meth:`save`, checking it completely.

        Parameters
        ----------
        path : str or os.PathLike
            A ``.npz`` or ``.json`` file; its suffix picks the format unless ``format``
            is given.
        format : {"npz", "json"}, optional
        memory_limit : int, optional
            Bytes reading may take (the file, its parse, the arrays its headers promise);
            default: the memory currently available. Checked before anything is read.

        Returns
        -------
        Triangulation

        Raises
        ------
        ValueError
            If the path is not a regular file (a device, a pipe, a folder), reading it
            would take more than ``memory_limit``, it cannot be parsed, its content does
            not match the digest stored in it, it is not a bderiv triangulation, has an
            unknown version, or any field fails the checks of :class:`Triangulation` (the
            message names the file and the field). Nothing in the file is ever unpickled.
            A file without a digest (written by bderiv before digests, or by another
            program) is read with the field checks alone. The ``.npz`` of a pair written
            by ``bderiv export --format both`` whose ``.json`` (same name) is from
            another save (an export interrupted between its two renames) is refused too.
        OSError
            If the file cannot be opened.

        Examples
        --------
        >>> import os, tempfile
        >>> import numpy as np
        >>> from bderiv import BDerivative, Triangulation
        >>> F = np.array([[1.0, 1.0], [2.0, 1.0], [1.0, 1.0], [2.0, 1.0]])
        >>> tri = BDerivative(np.eye(2), F).triangulation()
        >>> path = tri.save(os.path.join(tempfile.mkdtemp(), "tri.json"))
        >>> Triangulation.load(path)([-1.0, -2.0])
        array([-2., -2.])
        """
        path = text_path(path)
        source = f"triangulation file {path!r}"
        read = read_json if file_format(path, format) == "json" else read_npz
        data = read(path, source, memory_limit)
        check_pair(path, data, source)
        return cls.from_dict(data, source)


def save_files(tri, paths: dict, check=None) -> None:
    """Save ``tri`` to several files at once, all or none (``bderiv export``).

    Parameters
    ----------
    tri : Triangulation
    paths : dict
        ``{path: format}``, format ``"npz"`` or ``"json"``.
    check : callable, optional
        ``check({path: temporary path})`` once every file is written, before any replaces
        its target; if it raises, no target is touched (see
        :func:`bderiv.geometry._triangulation_io.write_files`).

    Notes
    -----
    Several files (``NAME.npz`` and ``NAME.json``, renamed in that order) are a pair:
    both carry one random token (header field ``pair``), so that the new ``.npz`` a kill
    between the renames leaves beside the earlier ``.json`` is refused when it is loaded
    (:func:`bderiv.geometry._triangulation_io.check_pair`).
    """
    header, arrays = tri._file_contents()
    if len(paths) > 1:  # one token in both: a half-replaced pair is refused on load
        header[PAIR] = uuid.uuid4().hex
    order = sorted(paths, key=lambda path: paths[path] != "npz")  # renamed: .npz first
    write_files({path: (paths[path], header, arrays) for path in order}, check)

