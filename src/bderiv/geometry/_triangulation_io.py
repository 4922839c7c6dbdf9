"""Triangulation files and data: parse them, and check every field before it is trusted.

A triangulation file (``.json`` or ``.npz``, written by :meth:`Triangulation.save`) may be
damaged or hostile. :func:`read_json` and :func:`read_npz` turn any parse failure into a
``ValueError`` naming the file (an ``.npz`` is never unpickled); :func:`check_data` checks
the header (format tag, version, sizes) and
:func:`~bderiv.geometry._triangulation_fields.check_fields` the arrays (dtypes, shapes,
finiteness, index ranges, every vertex used, non-degenerate cones), the same check that
guards ``Triangulation(pre, post, simplices, kernel, kernel_post)``.

Reading is bounded: only a regular file is opened (``/dev/zero``, a FIFO or a directory
is refused), and before anything is read its size (and, for a JSON file, the memory the
parse may take, :func:`json_parse_bytes`; for an ``.npz``, the sizes its members and their
headers promise) is checked against the memory limit. A file saved by bderiv carries a
sha256 digest of its content (:func:`json_digest`, :func:`npz_digest`), checked before the
fields: a changed digit is refused, never read as another map. Files without a digest
(written before the digest existed, or by another program) are still read, checked field
by field only.

Writing is all or nothing (:func:`write_files`, on :mod:`bderiv._support._safefiles`): every file
goes to a temporary file in the target's folder, is flushed and synced, and replaces the
target (``os.replace``) only when all of them are written; a failure (a full disk, an
exception, Ctrl-C) leaves the previous files as they were and removes the temporaries.
Only a kill between two renames can leave a new file beside an old one: files saved
together carry one token (:data:`PAIR`), and :func:`check_pair` refuses the ``.npz`` of a
pair whose ``.json`` holds another.

Version 1 files hold maps that are the identity on the kernel (the B-derivative at an event
point); version 2 adds ``kernel_post``, the images of the kernel basis (a flow map's
triangulation, whose linear stages move the kernel). A map that version 1 can hold is
written as version 1, so older readers still read it.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import re
import tokenize
import zipfile
import zlib

import numpy as np

from .._support._safefiles import open_regular, read_regular, write_all
from .._support._validate import check_memory
from ._triangulation_fields import FIELDS, check_fields

#: tag written into every saved file, checked on load
FILE_FORMAT = "bderiv.triangulation"
FILE_VERSION = 2
#: the arrays each file version holds
VERSION_FIELDS = {1: FIELDS[:4], 2: FIELDS}
#: the header field holding the sha256 digest of a file's content
DIGEST = "sha256"
#: the header field of files saved together (``bderiv export --format both``): one random
#: token (32 hex digits) in both, compared with the other file's when either is loaded
PAIR = "pair"
#: the first bytes of a pair's JSON file read for its token (its header comes first)
PAIR_HEAD_BYTES = 4096
#: what reading a damaged or hostile .npz can raise (BadZipFile for a truncated archive or
#: a bad CRC, zlib.error for a corrupt member, ValueError for object arrays with
#: allow_pickle=False, NotImplementedError for a compression method changed by a flipped
#: bit, RuntimeError for a member flagged as encrypted, KeyError / IndexError /
#: OverflowError for garbled zip records, tokenize.TokenError for an .npy header that does
#: not parse: numpy tokenizes it again, as a Python 2 header, before the member's CRC is
#: checked)
_NPZ_ERRORS = (OSError, EOFError, ValueError, zipfile.BadZipFile, zlib.error,
               NotImplementedError, RuntimeError, KeyError, IndexError, OverflowError,
               tokenize.TokenError)


def check_data(data, source: str) -> dict:
    """Check a whole triangulation description (:meth:`Triangulation.to_dict` layout).

    Parameters
    ----------
    data : dict
        ``format``, ``version``, ``n_events``, ``dim`` and the arrays of
        :data:`~bderiv.geometry._triangulation_fields.FIELDS`.
    source : str
        What ``data`` came from, named in every message.

    Returns
    -------
    dict
        The checked arrays (see :func:`~bderiv.geometry._triangulation_fields.check_fields`).

    Raises
    ------
    ValueError
        Naming ``source`` and the field, what was expected and what came.
    """
    version = _check_header(data, source)
    missing = [name for name in (*VERSION_FIELDS[version], "n_events", "dim")
               if name not in data]
    if missing:
        raise ValueError(f"{source}: triangulation data lacks the field(s) {missing}")
    fields = check_fields({name: data[name] for name in VERSION_FIELDS[version]}, source,
                          ValueError)
    d, n = fields["pre"].shape[1], fields["simplices"].shape[1] - 1
    for name, want, why in (("n_events", n, "columns of simplices - 1"),
                            ("dim", d, "columns of pre")):
        got = data[name]
        if isinstance(got, bool) or not isinstance(got, int | np.integer) or got != want:
            raise ValueError(
                f"{source}: field {name!r} must be the integer {want} (the {why}), got {got!r}"
            )
    return fields


def _check_header(data, source: str) -> int:
    """The file version of ``data`` after checking its format tag."""
    if not isinstance(data, dict) or data.get("format") != FILE_FORMAT:
        got = data.get("format") if isinstance(data, dict) else type(data).__name__
        raise ValueError(
            f"{source} is not a bderiv triangulation: expected a mapping with "
            f"format={FILE_FORMAT!r}, got {got!r}"
        )
    version = data.get("version")
    if isinstance(version, bool) or not isinstance(version, int) or version not in VERSION_FIELDS:
        raise ValueError(
            f"{source}: triangulation file version {version!r} is not supported (this "
            f"bderiv reads versions {', '.join(map(str, VERSION_FIELDS))})"
        )
    return version


def read_json(path: str, source: str, memory_limit=None):
    """The parsed JSON of ``path``, its digest checked (and removed) when it has one.

    Any parse failure is a ``ValueError`` naming ``source``; so are a file that is not a
    regular one, a text whose parse would take more than ``memory_limit`` bytes (default:
    the memory available, :func:`json_parse_bytes`) and a digest that does not match.
    """
    text = read_regular(path, source, memory_limit, JSON_BYTES_PER_BYTE, " parsed as JSON")
    check_memory(json_parse_bytes(text), memory_limit, f"reading {source} (JSON)")
    try:
        data = json.loads(text)
    except (ValueError, RecursionError, MemoryError) as exc:  # JSONDecodeError, Unicode...
        what = {RecursionError: "nested too deeply", MemoryError: "out of memory"}.get(
            type(exc), str(exc))
        raise ValueError(f"{source} is not valid JSON: {what}") from None
    if isinstance(data, dict) and DIGEST in data:
        stored = data.pop(DIGEST)
        _check_digest(stored, json_digest(data), source)
    return data


#: the least memory a byte of JSON takes, read and parsed (the first term of
#: :func:`json_parse_bytes`): checked from the file's size before it is read
JSON_BYTES_PER_BYTE = 5


def json_parse_bytes(text: bytes) -> int:
    """An upper bound of the bytes ``json.loads(text)`` and its digest check take.

    Python's parser makes an object for every value: up to 32 bytes for a number (and its
    list slot) of 2 or more characters, 64 to 96 for an empty list or object, the text
    decoded and copied; counting the characters that open them bounds the total (checked
    against tracemalloc on numbers, strings, escapes and nested containers, the worst
    case being an empty container per 3 bytes: about 30 bytes per byte).
    """
    return (JSON_BYTES_PER_BYTE * len(text) + 96 * text.count(b"{") + 80 * text.count(b"[")
            + 48 * (text.count(b",") + text.count(b":") + 1) + 32 * text.count(b'"'))


def json_digest(data) -> str:
    """sha256 (hex) of the canonical JSON of ``data`` (keys sorted, no spaces).

    Floats are written with all their digits (``repr``), so a parsed file gives back the
    text its writer hashed: any changed number, key or value changes the digest.
    """
    text = json.dumps(data, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def npz_digest(header: dict, arrays: dict) -> str:
    """sha256 (hex) of a header (without its digest) and arrays, as an ``.npz`` holds them.

    Each array contributes its name, dtype, shape and bytes (C order), so a file whose
    dtype or shape record changed does not match either.
    """
    h = hashlib.sha256(json.dumps(header, sort_keys=True, separators=(",", ":")).encode())
    for name in sorted(arrays):
        arr = np.ascontiguousarray(arrays[name])
        h.update(f"|{name}|{arr.dtype.str}|{arr.shape}|".encode())
        h.update(arr.data if arr.size else b"")
    return h.hexdigest()


def _check_digest(stored, actual: str, source: str) -> None:
    if stored != actual:
        raise ValueError(
            f"{source} is damaged: its content does not match the {DIGEST} digest stored "
            f"in it when it was saved (got {str(stored)[:64]!r}, the content gives "
            f"{actual!r}); restore the file from a copy, or save the map again"
        )


def read_npz(path: str, source: str, memory_limit=None):
    """The ``meta`` header of an ``.npz`` (a dict, if valid) with its arrays added.

    Never unpickles; a damaged archive or member (truncated, corrupt, pickled objects, a
    header claiming an impossible size) is a ``ValueError`` naming ``source`` and the field.
    Before any array is read, the bytes each member's ``.npy`` header promises are checked
    against the member's size in the archive and, in total, against ``memory_limit``
    (default: the memory available). The digest, when ``meta`` has one, is checked on the
    arrays as read.
    """
    with open_regular(path, source) as fh:
        try:
            npz = np.load(fh, allow_pickle=False)
        except _NPZ_ERRORS as exc:
            raise ValueError(f"{source} cannot be read as .npz: {exc}") from None
        if not isinstance(npz, np.lib.npyio.NpzFile):
            raise ValueError(f"{source} is not an .npz archive (it holds one bare array)")
        with npz:
            if "meta" not in npz.files:
                raise ValueError(f"{source} is not a bderiv triangulation (no 'meta' entry)")
            names = ["meta", *(k for k in FIELDS if k in npz.files)]
            total = sum(_field(source, name, _promised_bytes, npz.zip, name) for name in names)
            check_memory(total, memory_limit, f"reading {source} (its arrays)")
            data = _field(source, "meta", _meta, npz)
            if isinstance(data, dict):
                arrays = {name: _field(source, name, npz.__getitem__, name)
                          for name in names[1:]}
                if DIGEST in data:
                    stored = data.pop(DIGEST)
                    _check_digest(stored, npz_digest(data, arrays), source)
                data.update(arrays)
    return data


def _field(source: str, name: str, read, *args):
    """``read(*args)``, any failure of a damaged member a ``ValueError`` naming it."""
    try:
        return read(*args)
    except (*_NPZ_ERRORS, RecursionError, MemoryError) as exc:
        what = "nested too deeply" if isinstance(exc, RecursionError) else str(exc)
        raise ValueError(f"{source}: field {name!r} cannot be read: {what}") from None


def _meta(npz):
    """The parsed JSON header of an ``.npz`` (a 0-d string array)."""
    meta = npz["meta"]
    if meta.dtype.kind != "U" or meta.ndim != 0:
        raise ValueError(f"expected a JSON text, got a {meta.dtype} array of shape "
                         f"{meta.shape}")
    return json.loads(str(meta))


def _promised_bytes(zf: zipfile.ZipFile, name: str) -> int:
    """Bytes the ``.npy`` header of member ``name`` promises, no more than the member holds.

    numpy allocates what the header says before it reads the data: a header claiming more
    than the member's uncompressed size (from the archive's directory) is refused here.
    """
    info = zf.getinfo(f"{name}.npy")
    with zf.open(info) as member:
        version = np.lib.format.read_magic(member)
        read_header = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                       else np.lib.format.read_array_header_2_0)
        shape, _, dtype = read_header(member)
        header_bytes = member.tell()
    count = 1
    for s in shape:
        count *= int(s)  # Python ints: no overflow for any claim
    promised = count * dtype.itemsize
    if promised > info.file_size - header_bytes:
        raise ValueError(f"its header promises {promised} bytes of shape {shape}, but the "
                         f"member holds {info.file_size - header_bytes}")
    return promised


def check_pair(path: str, data, source: str) -> None:
    """Refuse the ``.npz`` of a pair whose ``.json`` is not from the same save.

    ``bderiv export --format both`` writes ``NAME.npz`` and ``NAME.json`` with one token
    (:data:`PAIR`) and renames the ``.npz`` first: a kill between the two renames leaves
    the new ``.npz`` beside the earlier ``.json``. Loading that ``.npz`` finds the
    ``.json`` with another token, or none, and is refused. The ``.json`` of a pair is never
    the newer file (it is renamed last), so it loads whatever the ``.npz`` holds: after
    such a kill it is the earlier export, whole. No ``.json`` beside it: no pair to check.
    """
    token = data.get(PAIR) if isinstance(data, dict) else None
    if token is None:
        return
    if not (isinstance(token, str) and re.fullmatch("[0-9a-f]{32}", token)):
        raise ValueError(f"{source}: field {PAIR!r} must be 32 hex digits (a token of "
                         f"bderiv export), got {str(token)[:64]!r}")
    base, ext = os.path.splitext(path)
    other = f"{base}.json"
    if ext.lower() != ".npz" or not os.path.lexists(other):
        return
    found = _json_pair_token(other)
    if found != token:
        holds = "no pair token" if found is None else f"the token {found[:8]}..."
        raise ValueError(
            f"{source} was exported together with {other!r} (both carry the pair token "
            f"{token[:8]}...), but {other!r} holds {holds}: the export was interrupted "
            f"between its two renames (the .npz is renamed first), or the .json was "
            f"replaced since. Export again, or move {other!r} away to read this file alone"
        )


def _json_pair_token(path: str):
    """The :data:`PAIR` token of the triangulation JSON file ``path``, or None (none, or
    unreadable), read from its first :data:`PAIR_HEAD_BYTES` (the header is written
    first)."""
    try:
        with open_regular(path, path) as fh:
            head = fh.read(PAIR_HEAD_BYTES)
    except (OSError, ValueError):
        return None
    found = re.search(rb'"pair": "([0-9a-f]{32})"', head)
    return found.group(1).decode() if found else None


def file_format(path: str, format: str | None) -> str:
    """``format``, or the suffix of ``path``: ``"npz"`` or ``"json"`` (else ``ValueError``)."""
    if format is None:
        format = os.path.splitext(path)[1].lstrip(".").lower()
    if format not in ("npz", "json"):
        raise ValueError(
            f"unknown triangulation file format {format!r} for {path!r}: use a .npz or "
            f".json file name, or format='npz' / 'json'"
        )
    return format


def write_files(targets: dict, check=None) -> None:
    """Write several triangulation files, all or none
    (:func:`bderiv._support._safefiles.write_all`).

    Parameters
    ----------
    targets : dict
        ``{path: (format, header, arrays)}``: ``format`` ``"json"`` or ``"npz"``, ``header``
        the fields ``format``, ``version``, ``n_events``, ``dim``, ``arrays`` the arrays of
        the file version (name -> ndarray).
    check : callable, optional
        ``check({path: temporary path})``, called when every file is written and synced,
        before any target is replaced (to read them back): if it raises, nothing is
        replaced.
    """
    write_all({path: (fmt == "npz", functools.partial(_write, fmt, header, arrays))
               for path, (fmt, header, arrays) in targets.items()}, check)


def _write(fmt: str, header: dict, arrays: dict, fh) -> None:
    WRITERS[fmt](fh, header, arrays)  # looked up at the write: tests replace a writer


def _write_json(fh, header: dict, arrays: dict) -> None:
    """The header, its digest and the arrays as nested lists (floats with all digits)."""
    data = {**header, **{name: arr.tolist() for name, arr in arrays.items()}}
    json.dump({**header, DIGEST: json_digest(data), **data}, fh)
    fh.write("\n")


def _write_npz(fh, header: dict, arrays: dict) -> None:
    """The arrays and a JSON ``meta`` (the header and the digest), compressed."""
    meta = {**header, DIGEST: npz_digest(header, arrays)}
    np.savez_compressed(fh, meta=np.array(json.dumps(meta)), **arrays)


#: the writer of each format: ``writer(fh, header, arrays)``
WRITERS = {"json": _write_json, "npz": _write_npz}
