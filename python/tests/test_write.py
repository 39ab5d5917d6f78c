"""numpy → PHM → numpy: `write` stores arrays exactly as given, for every element type and
component count, and refuses what PHM cannot hold with a ValueError."""

import numpy as np
import photonkit
import pytest

DTYPES = [np.uint8, np.uint16, np.uint32, np.uint64, np.int8, np.int16, np.int32, np.int64, np.float32, np.float64]


def photons(n, seed=0):
    rng = np.random.default_rng(seed)
    return {
        "position": rng.uniform(-1, 1, (n, 3)).astype(np.float32),
        "flux": rng.uniform(0, 1e-3, (n, 3)).astype(np.float32),
    }


def extremes(dtype, shape, rng):
    """Random values over the type's whole range, with its extremes (and for floats NaN,
    infinities, -0.0 and subnormals, which a column other than position and flux may hold)."""
    if np.issubdtype(dtype, np.integer):
        info = np.iinfo(dtype)
        a = rng.integers(info.min, info.max, shape, dtype=dtype, endpoint=True)
        a.flat[:2] = [info.min, info.max]
    else:
        bits = {np.float32: np.uint32, np.float64: np.uint64}[dtype]
        a = rng.integers(0, np.iinfo(bits).max, shape, dtype=bits, endpoint=True).view(dtype)
        special = [np.nan, np.inf, -np.inf, -0.0, np.finfo(dtype).smallest_subnormal, np.finfo(dtype).max]
        a.flat[: len(special)] = special
    return a


@pytest.mark.parametrize("dtype", DTYPES, ids=lambda d: np.dtype(d).name)
@pytest.mark.parametrize("components", [1, 2, 3, 4, 7])
def test_every_column_type_round_trips_exactly(tmp_path, dtype, components):
    n = 1000
    rng = np.random.default_rng(components)
    columns = photons(n)
    shape = (n,) if components == 1 else (n, components)
    columns["extra"] = extremes(dtype, shape, rng)
    m = photonkit.write(tmp_path / "m.phm", columns)
    for name, given in columns.items():
        back = m[name]
        assert back.dtype == given.dtype and back.shape == given.shape, name
        assert back.tobytes() == given.tobytes(), name  # bit for bit: NaN payloads, -0.0
    again = photonkit.open(tmp_path / "m.phm")
    assert again["extra"].tobytes() == columns["extra"].tobytes()


def test_the_catalogue_columns_and_emitters_round_trip(tmp_path):
    n = 500
    rng = np.random.default_rng(3)
    columns = photons(n)
    normal = rng.normal(size=(n, 3))
    columns["normal"] = (normal / np.linalg.norm(normal, axis=1, keepdims=True)).astype(np.float32)
    columns["emitter"] = rng.integers(0, 2, n, dtype=np.uint16)
    columns["params"] = rng.uniform(0, 1, (n, 3)).astype(np.float32)
    columns["bounces"] = rng.integers(1, 5, n, dtype=np.uint8)
    columns["emission_index"] = np.arange(n, dtype=np.uint64)
    emitters = [
        {"kind": "collimated", "parameterisation": "rect_uv", "power_w": 2.0, "param_measure": 0.25},
        {"kind": "point", "parameterisation": "direction", "power_w": 1.0, "colour": [1.0, 0.5, 0.25]},
    ]
    m = photonkit.write(tmp_path / "m.phm", columns, emitters=emitters, units={"length": "m", "flux": "W"})
    for name, given in columns.items():
        assert m[name].tobytes() == given.tobytes(), name
    got = m.emitters
    assert [(e["id"], e["kind"], e["param_dims"]) for e in got] == [(0, "collimated", 2), (1, "point", 3)]
    assert got[1]["colour"] == [1.0, 0.5, 0.25] and got[0]["param_measure"] == 0.25
    assert m.history[-1]["stage"] == "write" and m.history[-1]["parameters"]["from"] == "python"
    # The header of one map carries into another: emitters and history as dicts.
    copy = photonkit.write(tmp_path / "copy.phm", m.columns, emitters=m.emitters, history=m.history[:-1])
    assert copy.emitters == m.emitters
    assert [r["stage"] for r in copy.history] == ["write"]
    # A map written from Python is one the pipeline takes: detection with its parameters.
    assert photonkit.detect(copy, kc=10).state == "detected"


def test_arrays_in_any_layout_are_written_as_their_values(tmp_path):
    n = 64
    base = photons(n)
    strided = np.asfortranarray(base["position"])
    every_other = np.repeat(base["flux"], 2, axis=0)[::2]
    m = photonkit.write(tmp_path / "m.phm", {"position": strided, "flux": every_other, "w": [1.0] * n})
    assert np.array_equal(m["position"], base["position"])
    assert np.array_equal(m["flux"], base["flux"])
    assert m["w"].dtype == np.float64  # a list becomes numpy's array of it
    assert m.emitters[0]["kind"] == "external" and m.emitters[0]["param_dims"] == 0
    assert m.emitters[0]["power_w"] == pytest.approx(float(base["flux"].astype(np.float64).sum()), rel=1e-6)


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda c: c.pop("flux"), "no flux column"),
        (lambda c: c.update(position=c["position"].astype(np.float64)), "'position' must be f32×3"),
        (lambda c: c.update(normal=np.zeros((10, 3), np.float64)), "normal"),
        (lambda c: c.update(extra=np.zeros(9, np.float32)), "column 'extra' holds 36 bytes, expected 40"),
        (lambda c: c.update(extra=np.zeros((10, 2, 2), np.float32)), "shape"),
        (lambda c: c.update(extra=np.zeros(10, np.float16)), "dtype"),
        (lambda c: c.update(extra=np.zeros(10, ">f4")), "big-endian"),
        (lambda c: c.update(extra=np.zeros(10, bool)), "dtype"),
        (lambda c: c.update(params=np.zeros((10, 2), np.float32)), "emitters="),
    ],
)
def test_what_phm_cannot_hold_is_a_value_error(tmp_path, change, message):
    columns = photons(10)
    change(columns)
    with pytest.raises(ValueError, match=message):
        photonkit.write(tmp_path / "m.phm", columns)
    assert not (tmp_path / "m.phm").exists()


def test_bad_emitters_and_state_are_value_errors(tmp_path):
    with pytest.raises(ValueError, match=r"emitters\[0\]"):
        photonkit.write(tmp_path / "m.phm", photons(4), emitters=[{"kind": "collimated"}])
    with pytest.raises(ValueError, match="'state'"):
        photonkit.write(tmp_path / "m.phm", photons(4), state="relaxed")
    with pytest.raises(ValueError, match="mapping"):
        photonkit.write(tmp_path / "m.phm", [1, 2, 3])
