"""Triangulation files: save to .npz / .json and load back the same map, exactly."""

from __future__ import annotations

import json

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
