"""Opening maps: columns are numpy arrays that view the memory map, read-only, whose base is
the map object; the header is a dict; the values are those an independent reader finds."""

import gc
import sys

import numpy as np
import photonkit
import pytest

from conftest import REPO, SAMPLES


NUMPY = {"u8": np.uint8, "u16": np.uint16, "u32": np.uint32, "u64": np.uint64, "i8": np.int8,
         "i16": np.int16, "i32": np.int32, "i64": np.int64, "f32": np.float32, "f64": np.float64}


def address(a):
    return a.__array_interface__["data"][0]


def independent_columns(path):
    """Every column as tools/phm.py (stdlib only, written from the spec) reads it."""
    sys.path.insert(0, str(REPO / "tools"))
    try:
        import phm
    finally:
        sys.path.pop(0)
    with open(path, "rb") as f:
        f.seek(0, 2)
        n = f.tell()
        f.seek(0)
        _, _, _, meta_len, _ = phm.read_preamble(f, n)
        meta = phm.parse_metadata(f.read(meta_len))
        return meta, {c["name"]: (c, phm.read_column(f, c, True)) for c in meta["columns"]}


@pytest.mark.parametrize("sample", ["collimated-cusp", "point-ring", "two-emitters", "dispersed-beam", "minimal"])
def test_columns_view_the_memory_map_read_only(sample):
    path = SAMPLES / f"{sample}.phm"
    m = photonkit.open(path)
    start, end = m.mapping
    assert end - start == path.stat().st_size
    meta, columns = independent_columns(path)
    assert m.keys() == [c["name"] for c in meta["columns"]]
    for name, (entry, values) in columns.items():
        a = m[name]
        # The array is the map's memory: its base is the map object, its data lies inside
        # the mapping at the column's offset, and nothing was copied.
        assert a.base is m
        assert address(a) == start + entry["offset"]
        assert start <= address(a) and address(a) + a.nbytes <= end
        assert not a.flags.owndata
        assert not a.flags.writeable
        with pytest.raises(ValueError):
            a.setflags(write=True)
        with pytest.raises(ValueError):
            a[...] = 0
        # Shape and type from the column table, values as the independent reader has them.
        assert a.shape == ((len(m),) if entry["components"] == 1 else (len(m), entry["components"]))
        assert a.dtype == NUMPY[entry["dtype"]]
        assert a.reshape(-1).tobytes() == values.tobytes()
    # A view of a view still leads back to the map.
    v = m["position"][1:, :2]
    assert v.base.base is m or v.base is m


def test_an_array_keeps_its_map_alive():
    m = photonkit.open(SAMPLES / "point-ring.phm")
    expected = np.array(m["flux"])  # a copy
    a = m["flux"]
    del m
    gc.collect()
    assert isinstance(a.base, photonkit.PhotonMap)
    assert np.array_equal(a, expected)


def test_the_header_is_a_dict_as_the_file_holds_it():
    path = SAMPLES / "two-emitters.phm"
    m = photonkit.open(path)
    meta, _ = independent_columns(path)
    assert m.metadata == meta
    assert m.emitters == meta["emitters"]
    assert m.history == meta["history"]
    assert m.state == meta["state"] == "traced"
    assert m.version == (1, 0)
    assert m.path == str(path)
    assert len(m) == meta["photon_count"]
    assert set(m.columns) == set(m.keys()) and "emitter" in m and "lambda2" not in m
    assert list(m) == m.keys()
    assert m.get("lambda2") is None
    with pytest.raises(KeyError, match="no column 'lambda2'"):
        m["lambda2"]


def test_a_map_in_memory_views_its_own_columns():
    d = photonkit.detect(SAMPLES / "collimated-cusp.phm", kc=20)
    assert d.path is None and d.mapping is None and d.version is None
    assert d.name == str(SAMPLES / "collimated-cusp.phm")
    assert d.state == "detected"
    b = d["basis_u"]
    assert b.base is d and not b.flags.writeable and b.shape == (len(d), 3)
    assert d.metadata["photon_count"] == len(d)
    assert [c["name"] for c in d.metadata["columns"]] == d.keys()
    assert d.history[-1]["stage"] == "detect"
    assert "in memory" in repr(d)
