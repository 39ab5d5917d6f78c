"""Bad input raises: ValueError for a bad argument, OSError for a file that cannot be read or
written, PhotonkitError (a RuntimeError) for the rest, each with the message the command line
prints after `photonkit: error: `; nothing is left behind."""

import numpy as np
import photonkit
import pytest

from conftest import SAMPLES, cli_error


@pytest.fixture
def files(tmp_path):
    (tmp_path / "not-a-map.phm").write_bytes(b"plain text, not a photon map\n" * 4)
    good = (SAMPLES / "collimated-cusp.phm").read_bytes()
    (tmp_path / "truncated.phm").write_bytes(good[: len(good) // 2])
    corrupt = bytearray(good)
    corrupt[-10] ^= 0xFF  # a photon's bytes: the column's checksum no longer matches
    (tmp_path / "corrupt.phm").write_bytes(bytes(corrupt))
    photonkit.write(
        tmp_path / "no-params.phm",
        {"position": np.zeros((50, 3), np.float32) + np.arange(50, dtype=np.float32)[:, None], "flux": np.ones((50, 3), np.float32)},
    )
    (tmp_path / "bad-scene.toml").write_text("[camera]\neye = [0, 0]\n")
    return tmp_path


# (the command line's arguments, the same call in Python, the exception it raises)
CASES = [
    (["detect", "missing.phm", "-o", "out.phm"], lambda: photonkit.detect("missing.phm"), FileNotFoundError),
    (["detect", "not-a-map.phm", "-o", "out.phm"], lambda: photonkit.detect("not-a-map.phm"), photonkit.PhotonkitError),
    (["detect", "truncated.phm", "-o", "out.phm"], lambda: photonkit.open("truncated.phm"), photonkit.PhotonkitError),
    (["relax", "corrupt.phm", "-o", "out.phm"], lambda: photonkit.relax("corrupt.phm"), photonkit.PhotonkitError),
    (
        ["detect", "no-params.phm", "-o", "out.phm", "--method", "param-pca"],
        lambda: photonkit.detect("no-params.phm", method="param-pca"),
        photonkit.PhotonkitError,
    ),
    (["collapse", "no-params.phm", "-o", "out.phm"], lambda: photonkit.collapse("no-params.phm"), photonkit.PhotonkitError),
    (
        ["detect", "no-params.phm", "-o", "out.phm", "--kc", "2"],
        lambda: photonkit.detect("no-params.phm", kc=2),
        ValueError,
    ),
    (
        ["relax", "no-params.phm", "-o", "out.phm", "--epsilon=-1"],
        lambda: photonkit.relax("no-params.phm", epsilon=-1),
        ValueError,
    ),
    (
        ["relax", "no-params.phm", "-o", "out.phm", "--spectral-window=-1"],
        lambda: photonkit.relax("no-params.phm", spectral_window=-1),
        photonkit.PhotonkitError,
    ),
    (["trace", "bad-scene.toml", "-o", "out.phm"], lambda: photonkit.trace("bad-scene.toml", "out.phm"), photonkit.PhotonkitError),
    (["trace", "no-scene.toml", "-o", "out.phm"], lambda: photonkit.trace("no-scene.toml"), FileNotFoundError),
    (
        ["detect", "no-params.phm", "-o", "no-params.phm"],
        lambda: photonkit.detect(photonkit.open("no-params.phm"), "no-params.phm"),
        FileExistsError,
    ),
    (
        ["render", "no-params.phm", "-o", "out.exr", "--plane", "z=500"],
        lambda: photonkit.render("no-params.phm", "out.exr", plane="z=500"),
        ValueError,
    ),
    (
        ["render", "no-params.phm", "-o", "out.exr", "--fov", "200"],
        lambda: photonkit.render("no-params.phm", "out.exr", fov=200),
        ValueError,
    ),
]


@pytest.mark.parametrize("args, call, exception", CASES, ids=lambda c: " ".join(c) if isinstance(c, list) else "")
def test_bad_input_raises_with_the_command_lines_message(files, run_cli, monkeypatch, args, call, exception):
    expected = cli_error(run_cli(*args, check=False))
    monkeypatch.chdir(files)  # the same relative paths as the command line's
    with pytest.raises(exception) as raised:
        call()
    assert str(raised.value) == expected
    assert not (files / "out.phm").exists() and not (files / "out.exr").exists()
    assert not list(files.glob(".*.tmp")), "a temporary file was left behind"


def test_photonkit_error_is_a_runtime_error():
    assert issubclass(photonkit.PhotonkitError, RuntimeError)


@pytest.mark.parametrize(
    "call, message",
    [
        (lambda: photonkit.trace(photons=0), "--photons and --stored need at least 1"),
        (lambda: photonkit.trace(photons=1.5), "'1.5' is not a whole number of photons"),
        (lambda: photonkit.trace(photons=10, stored=10), "cannot be given together"),
        (lambda: photonkit.trace(photons=10, shard="3/3"), "0 ≤ i < n"),
        (lambda: photonkit.trace(photons=10, memory="lots"), "is not a size such as 512M"),
        (lambda: photonkit.trace(photons=10, store="all"), "expected one of caustic, direct"),
        (lambda: photonkit.trace(photons=10, threads=0), "threads needs at least 1"),
        (lambda: photonkit.detect(SAMPLES / "minimal.phm", beta=float("nan")), "not a finite number"),
        (lambda: photonkit.render(SAMPLES / "minimal.phm", eye=(0, 1)), "expected three finite numbers"),
        (lambda: photonkit.render(SAMPLES / "minimal.phm", plane="w=0"), "the plane's axis is x, y or z"),
        (lambda: photonkit.render(SAMPLES / "minimal.phm", estimator="fast"), "expected one of knn"),
        (lambda: photonkit.compare(methods=["best"]), "unknown method 'best'"),
    ],
)
def test_bad_arguments_are_value_errors(call, message):
    with pytest.raises(ValueError, match=message):
        call()


def test_a_path_argument_must_be_a_path():
    with pytest.raises(TypeError):
        photonkit.open(42)
