"""Triangulation files: save to .npz / .json and load back the same map, exactly."""

from __future__ import annotations

import json
import re
import zipfile

import numpy as np
import pytest
from numpy.testing import assert_array_equal
from reference import random_system

import bderiv
from bderiv import BDerivative, Triangulation, load_triangulation

FIELDS = ("pre", "post", "simplices", "kernel")


@pytest.fixture(params=[(2, 2), (3, 3), (2, 4)], ids=lambda p: f"n{p[0]}d{p[1]}")
def tri_bd(request):
    n, d = request.param
    Dh, F = random_system(np.random.default_rng(n * 10 + d), n, d)
    bd = BDerivative(Dh, F)
    return bd.triangulation(), bd


@pytest.mark.parametrize("suffix", [".npz", ".json"])
def test_round_trip_is_exact(tmp_path, tri_bd, suffix):
    tri, bd = tri_bd
    path = tri.save(tmp_path / f"tri{suffix}")
    assert path == str(tmp_path / f"tri{suffix}")
    back = load_triangulation(path)
    assert isinstance(back, Triangulation)
    for name in FIELDS:
        assert_array_equal(getattr(back, name), getattr(tri, name))
        assert getattr(back, name).dtype == getattr(tri, name).dtype
    assert (back.n_events, back.dim) == (tri.n_events, tri.dim)
    V = np.random.default_rng(0).standard_normal((50, bd.dim))
    assert_array_equal(back(V), tri(V))
    np.testing.assert_allclose(back(V), bd(V), atol=1e-9 * np.abs(bd(V)).max())


def test_explicit_format_and_plain_readers(tmp_path, tri_bd):
    tri, _ = tri_bd
    p = tri.save(tmp_path / "tri.dat", format="json")
    data = json.loads((tmp_path / "tri.dat").read_text())
    assert data["format"] == "bderiv.triangulation" and data["version"] == 1
    assert np.array(data["simplices"]).shape == tri.simplices.shape
    assert_array_equal(Triangulation.load(p, format="json").pre, tri.pre)
    q = tri.save(tmp_path / "tri.bin", format="npz")
    with np.load(q) as npz:  # readable by numpy alone
        assert set(npz.files) == {"meta", *FIELDS}
        assert_array_equal(npz["post"], tri.post)
    assert_array_equal(bderiv.load_triangulation(q, "npz").post, tri.post)


@pytest.fixture
def moved_kernel():
    """A triangulation whose map is not the identity on the kernel (n = 2, d = 4)."""
    rng = np.random.default_rng(5)
    Dh, F = random_system(rng, 2, 4)
    bd = BDerivative(Dh, F)
    before = np.eye(4) + 0.3 * rng.standard_normal((4, 4))
    after = np.eye(4) + 0.3 * rng.standard_normal((4, 4))
    return bd.triangulation().composed(before, after)


@pytest.mark.parametrize("suffix", [".npz", ".json"])
def test_version_2_round_trip(tmp_path, moved_kernel, suffix):
    """A map that moves the kernel is written as version 2 with ``kernel_post``."""
    tri = moved_kernel
    assert not np.allclose(tri.kernel, tri.kernel_post)
    assert tri.to_dict()["version"] == 2 and "kernel_post" in tri.to_dict()
    back = load_triangulation(tri.save(tmp_path / f"tri{suffix}"))
    for name in (*FIELDS, "kernel_post"):
        assert_array_equal(getattr(back, name), getattr(tri, name))
    V = np.random.default_rng(1).standard_normal((40, 4))
    assert_array_equal(back(V), tri(V))
    assert_array_equal(back.inverse(V), tri.inverse(V))


def test_version_1_files_have_no_kernel_post(tmp_path, tri_bd):
    """The event-point map stays a version 1 file (readable by older bderiv)."""
    tri, _ = tri_bd
    assert_array_equal(tri.kernel_post, tri.kernel)
    assert "kernel_post" not in tri.to_dict()
    with np.load(tri.save(tmp_path / "tri.npz")) as npz:
        assert "kernel_post" not in npz.files


def test_version_2_kernel_post_checked(tmp_path, moved_kernel):
    data = moved_kernel.to_dict()
    refused(write_json(tmp_path / "s.json", data | {"kernel_post": [[1.0]] * 4}),
            r"field 'kernel_post' must have shape \(d, d - n\) = \(4, 2\)")
    flat = np.array(data["kernel_post"])
    flat[:, 1] = flat[:, 0]  # the two kernel images collapse: no post cone spans R^4
    refused(write_json(tmp_path / "f.json", data | {"kernel_post": flat.tolist()}),
            "spans less than R\\^4 with the post vertices", "kernel_post")


def test_public_name():
    assert "load_triangulation" in bderiv.__all__


def test_bad_files(tmp_path, tri_bd):
    tri, _ = tri_bd
    with pytest.raises(ValueError, match="unknown triangulation file format 'txt'"):
        tri.save(tmp_path / "tri.txt")
    with pytest.raises(ValueError, match="unknown triangulation file format"):
        load_triangulation(tmp_path / "tri.txt")
    other = tmp_path / "other.json"
    other.write_text(json.dumps({"hello": 1}))
    with pytest.raises(ValueError, match="not a bderiv triangulation"):
        load_triangulation(other)
    broken = tmp_path / "broken.json"
    broken.write_text("{not json")
    with pytest.raises(ValueError, match="not valid JSON"):
        load_triangulation(broken)
    future = tri.to_dict() | {"version": 99}
    (tmp_path / "future.json").write_text(json.dumps(future))
    with pytest.raises(ValueError, match="version 99 is not supported"):
        load_triangulation(tmp_path / "future.json")
    partial = {k: v for k, v in tri.to_dict().items() if k != "kernel"}
    with pytest.raises(ValueError, match=r"lacks the field\(s\) \['kernel'\]"):
        Triangulation.from_dict(partial)
    np.savez(tmp_path / "plain.npz", pre=tri.pre)
    with pytest.raises(ValueError, match="no 'meta' entry"):
        load_triangulation(tmp_path / "plain.npz")
    (tmp_path / "junk.npz").write_bytes(b"not a zip file at all")
    with pytest.raises(ValueError):
        load_triangulation(tmp_path / "junk.npz")


# -- hostile files: each is refused on load with a ValueError naming the file and the field --


@pytest.fixture
def tri():
    F = np.array([[1.0, 1.0], [2.0, 1.0], [1.0, 3.0], [2.0, 2.0]])
    return BDerivative(np.eye(2), F).triangulation()


def write_json(path, data, **dump):
    path.write_text(json.dumps(data, **dump))
    return path


def write_npz(path, tri, meta=None, **fields):
    """An .npz laid out as Triangulation.save does, with some fields replaced."""
    meta = {k: v for k, v in tri.to_dict().items() if k not in FIELDS} if meta is None else meta
    arrays = {k: getattr(tri, k) for k in FIELDS} | fields
    with open(path, "wb") as fh:
        np.savez(fh, meta=np.array(json.dumps(meta)), **{k: v for k, v in arrays.items()
                                                         if v is not None})
    return path


def refused(path, *fragments):
    """Load ``path``; the ValueError must name the file and contain every fragment."""
    with pytest.raises(ValueError) as exc:
        load_triangulation(path)
    msg = str(exc.value)
    assert f"triangulation file {str(path)!r}" in msg, msg
    for fragment in fragments:
        assert re.search(fragment, msg), (fragment, msg)
    return msg


def test_truncated_npz(tmp_path, tri):
    tri.save(tmp_path / "whole.npz")
    data = (tmp_path / "whole.npz").read_bytes()
    for cut in (len(data) // 2, len(data) - 10):  # before and inside the central directory
        short = tmp_path / f"short{cut}.npz"
        short.write_bytes(data[:cut])
        refused(short, "cannot be read as .npz")


def test_corrupt_npz_member(tmp_path, tri):
    path = write_npz(tmp_path / "crc.npz", tri)
    with zipfile.ZipFile(path) as zf:
        info = zf.getinfo("pre.npy")
    raw = bytearray(path.read_bytes())
    # the local header: 30 bytes, then the name and the extra field, lengths at 26 and 28
    lengths = np.frombuffer(bytes(raw[info.header_offset + 26:info.header_offset + 30]), "<u2")
    start = info.header_offset + 30 + int(lengths.sum())
    raw[start + info.compress_size - 1] ^= 0xFF  # last data byte of pre.npy: CRC mismatch
    path.write_bytes(bytes(raw))
    refused(path, "field 'pre' cannot be read")


@pytest.mark.parametrize("value", ["nan", "inf", "-inf"])
def test_non_finite_vertex(tmp_path, tri, value):
    data = tri.to_dict()
    data["post"][2][1] = float(value)
    refused(write_json(tmp_path / "v.json", data), r"field 'post' must be finite, got "
            rf"post\[2, 1\] = {value}")
    pre = tri.pre.copy()
    pre[1, 0] = float(value)
    refused(write_npz(tmp_path / "v.npz", tri, pre=pre), r"field 'pre' must be finite")


@pytest.mark.parametrize("dtype, want", [(float, "integers"), (complex, "integers"),
                                         (bool, "integers"), ("U3", "integers")])
def test_simplices_of_the_wrong_dtype(tmp_path, tri, dtype, want):
    bad = tri.simplices.astype(dtype)
    refused(write_npz(tmp_path / "s.npz", tri, simplices=bad),
            rf"field 'simplices' must hold {want}", f"got dtype {bad.dtype}")


def test_float_simplices_in_json(tmp_path, tri):
    data = tri.to_dict()
    data["simplices"][1][1] = 1.5  # would have been truncated to vertex 1
    refused(write_json(tmp_path / "f.json", data), "field 'simplices' must hold integers",
            "float64")


def test_complex_vertices(tmp_path, tri):
    refused(write_npz(tmp_path / "c.npz", tri, post=tri.post + 1e-3j),
            "field 'post' must hold real numbers", "complex128")


def test_three_d_arrays(tmp_path, tri):
    # pre (5, 2) stored as (5, 1, 2) and simplices (4, 3) as (2, 2, 3): once reshaped silently
    refused(write_npz(tmp_path / "p.npz", tri, pre=tri.pre[:, None, :]),
            r"field 'pre' must be a 2-D array, got 3-D with shape \(5, 1, 2\)")
    refused(write_npz(tmp_path / "s.npz", tri, simplices=tri.simplices.reshape(2, 2, 3)),
            r"field 'simplices' must be a 2-D array, got 3-D")


def test_one_d_simplices(tmp_path, tri):
    data = tri.to_dict() | {"simplices": [0, 1, 3]}
    refused(write_json(tmp_path / "s.json", data), r"field 'simplices' must be a 2-D array, "
            r"got 1-D with shape \(3,\)")


@pytest.mark.parametrize("index", [5, -1, 2**40])
def test_index_out_of_range(tmp_path, tri, index):
    data = tri.to_dict()
    data["simplices"][2][1] = index
    refused(write_json(tmp_path / "i.json", data), "field 'simplices' must have vertex "
            r"indices 0\.\.4")


def test_index_beyond_int64(tmp_path, tri):
    bad = tri.simplices.astype(np.uint64)
    bad[0, 1] = np.iinfo(np.uint64).max
    refused(write_npz(tmp_path / "u.npz", tri, simplices=bad), "vertex indices 0..4",
            "18446744073709551615")


def test_unused_vertex_and_apex(tmp_path, tri):
    data = tri.to_dict()
    data["pre"].append([1.0, 1.0])
    data["post"].append([1.0, 1.0])
    refused(write_json(tmp_path / "u.json", data), r"vertices \[5\] are in no simplex")
    data = tri.to_dict()
    data["pre"][0] = [0.0, 1e-300]
    refused(write_json(tmp_path / "a.json", data), "field 'pre' must have vertex 0 .the apex. "
            "at the origin")
    sims = tri.simplices[:, ::-1]  # the apex no longer in column 0
    refused(write_npz(tmp_path / "c.npz", tri, simplices=sims), "column 0 .the apex. all 0")


def test_deep_json_nesting(tmp_path, tri):
    (tmp_path / "deep.json").write_text("[" * 100_000 + "]" * 100_000)
    refused(tmp_path / "deep.json", "not valid JSON: nested too deeply")
    data = tri.to_dict() | {"kernel": json.loads("[" * 200 + "]" * 200)}
    refused(write_json(tmp_path / "deep2.json", data), "field 'kernel'")


def test_ragged_and_junk_json(tmp_path, tri):
    data = tri.to_dict()
    data["pre"][1] = [1.0]
    refused(write_json(tmp_path / "r.json", data), "field 'pre' is not a rectangular array")
    data = tri.to_dict() | {"post": "hello"}
    refused(write_json(tmp_path / "h.json", data), "field 'post' must hold real numbers")
    (tmp_path / "bin.json").write_bytes(b"\xff\xfe\x00garbage")
    refused(tmp_path / "bin.json", "not valid JSON")


def test_wrong_version_and_format(tmp_path, tri):
    for version in (3, "1", True, None, 1.5, 1.0):
        data = tri.to_dict() | {"version": version}
        refused(write_json(tmp_path / "v.json", data), f"version {version!r} is not supported")
    # version 2 must carry the kernel images
    data = tri.to_dict() | {"version": 2}
    refused(write_json(tmp_path / "v2.json", data), r"lacks the field\(s\) \['kernel_post'\]")
    refused(write_json(tmp_path / "l.json", [1, 2]), "not a bderiv triangulation", "'list'")
    refused(write_npz(tmp_path / "v.npz", tri, meta={"format": FIELDS[0]}),
            "not a bderiv triangulation")


@pytest.mark.parametrize("field", [*FIELDS, "n_events", "dim"])
def test_missing_field(tmp_path, tri, field):
    data = {k: v for k, v in tri.to_dict().items() if k != field}
    refused(write_json(tmp_path / "m.json", data), rf"lacks the field\(s\) \['{field}'\]")
    if field in FIELDS:
        refused(write_npz(tmp_path / "m.npz", tri, **{field: None}),
                rf"lacks the field\(s\) \['{field}'\]")


@pytest.mark.parametrize("field, value", [("n_events", 3), ("dim", 3), ("dim", "2"),
                                          ("n_events", 2.0), ("dim", True)])
def test_sizes_disagree_with_the_arrays(tmp_path, tri, field, value):
    data = tri.to_dict() | {field: value}
    refused(write_json(tmp_path / "n.json", data), rf"field '{field}' must be the integer 2",
            f"got {value!r}")


def test_degenerate_simplex(tmp_path, tri):
    # two vertices of one ray: simplex [0, 1, 3] has no interior (once LinAlgError on call)
    data = tri.to_dict()
    data["pre"][3] = [2 * x for x in data["pre"][1]]
    refused(write_json(tmp_path / "d.json", data), "field 'simplices' must give non-degenerate",
            r"simplex 0 \[0, 1, 3\]", "pre vertices")
    post = tri.post.copy()
    post[4] = 0.0  # a post vertex at the apex: the image cones of its simplices collapse
    refused(write_npz(tmp_path / "d.npz", tri, post=post), "non-degenerate", "post vertices")
    flat = tri.pre.copy()
    assert_array_equal(flat[1], [1.0, 0.0])
    flat[4] = [3.0, 1e-16]  # parallel to vertex 1 up to rounding: as singular as equal
    refused(write_npz(tmp_path / "e.npz", tri, pre=flat), r"simplex 1 \[0, 1, 4\]")


def test_no_unpickling(tmp_path, tri):
    marker = tmp_path / "pwned"

    class Payload:
        def __reduce__(self):
            return (open, (str(marker), "w"))

    bad = np.empty(1, dtype=object)
    bad[0] = Payload()
    write_npz(tmp_path / "p.npz", tri, kernel=bad)
    refused(tmp_path / "p.npz", "field 'kernel' cannot be read", "allow_pickle")
    with open(tmp_path / "whole.npz", "wb") as fh:  # a pickle where the archive should be
        fh.write(b"\x80\x04" + b"\x00" * 20)
    refused(tmp_path / "whole.npz", "cannot be read as .npz")
    assert not marker.exists()


def test_bare_npy_and_impossible_header(tmp_path, tri):
    with open(tmp_path / "bare.npz", "wb") as fh:
        np.save(fh, tri.pre)
    refused(tmp_path / "bare.npz", "one bare array")
    path = write_npz(tmp_path / "huge.npz", tri, post=None)
    header = {"descr": "<f8", "fortran_order": False, "shape": (10**9, 10**9)}
    with zipfile.ZipFile(path, "a") as zf, zf.open("post.npy", "w", force_zip64=True) as fh:
        np.lib.format.write_array_header_1_0(fh, header)  # no data: a claim of 8e18 bytes
    refused(path, "field 'post' cannot be read")


def test_bad_npz_meta(tmp_path, tri):
    for meta in (np.array([1.0, 2.0]), np.array("{not json"), np.array("[" * 100_000)):
        with open(tmp_path / "m.npz", "wb") as fh:
            np.savez(fh, meta=meta, **{k: getattr(tri, k) for k in FIELDS})
        refused(tmp_path / "m.npz", "field 'meta' cannot be read")


def test_a_missing_folder_and_a_bytes_path_are_named(tmp_path):
    """Saving into a folder that does not exist named the hidden temporary file it could
    not make; a bytes path failed inside with "a bytes-like object is required"."""
    tri = BDerivative(np.eye(2), np.array([[1.0, 1], [2, 1], [1, 1], [2, 1]])).triangulation()
    target = tmp_path / "no" / "dir" / "y.npz"
    with pytest.raises(FileNotFoundError, match=r"its folder '.*no/dir' does not exist: "
                                                r"'.*y\.npz'"):
        tri.save(target)
    for call in (lambda: tri.save(b"y.npz"), lambda: load_triangulation(b"y.npz")):
        with pytest.raises(TypeError, match=r"path must be a str or an os.PathLike of a "
                                            r"str, got bytes b'y.npz'"):
            call()
