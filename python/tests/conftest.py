"""Shared fixtures: the repository, its samples, and the command-line program to compare with."""

import os
import shutil
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
SAMPLES = REPO / "samples"


def find_cli():
    """The `photonkit` program: $PHOTONKIT_CLI, else a release or debug build in the target
    directory ($CARGO_TARGET_DIR or the repository's target/), else one on the PATH."""
    given = os.environ.get("PHOTONKIT_CLI")
    if given:
        assert Path(given).is_file(), f"PHOTONKIT_CLI={given} is not a file"
        return Path(given).resolve()
    target = Path(os.environ.get("CARGO_TARGET_DIR", REPO / "target"))
    for build in ("release", "debug"):
        if (target / build / "photonkit").is_file():
            return (target / build / "photonkit").resolve()
    found = shutil.which("photonkit")
    return Path(found) if found else None


@pytest.fixture(scope="session")
def cli():
    path = find_cli()
    if path is None:
        pytest.skip("no photonkit program (cargo build --release, or set PHOTONKIT_CLI)")
    return path


@pytest.fixture
def reproducible(monkeypatch):
    """SOURCE_DATE_EPOCH set, as for the command line: stage records carry this time and no
    measured durations, so the same stage writes the same bytes."""
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1767225600")


@pytest.fixture
def run_cli(cli, tmp_path):
    """Runs `photonkit ARGS…` in tmp_path; returns the completed process (check=False)."""

    def run(*args, check=True):
        p = subprocess.run(
            [str(cli), "--quiet", *map(str, args)], cwd=tmp_path, capture_output=True, text=True
        )
        if check and p.returncode != 0:
            raise AssertionError(f"photonkit {' '.join(map(str, args))} failed: {p.stderr}")
        return p

    return run


def cli_error(process):
    """The message after `photonkit: error: ` on the command line's standard error."""
    assert process.returncode != 0, process.stderr
    lines = [l for l in process.stderr.splitlines() if l.startswith("photonkit: error: ")]
    assert lines, process.stderr
    return lines[-1][len("photonkit: error: ") :]
