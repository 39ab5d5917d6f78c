"""docs/examples/radial_profile.py runs (small), with or without matplotlib."""

import subprocess
import sys

from conftest import REPO


def test_the_radial_profile_example_runs(tmp_path):
    script = REPO / "docs" / "examples" / "radial_profile.py"
    p = subprocess.run(
        [sys.executable, str(script), "--photons", "2e4", "--pixels", "40", "--out", str(tmp_path / "p.png")],
        capture_output=True, text=True, cwd=tmp_path,
    )
    assert p.returncode == 0, p.stderr
    assert "photons stored" in p.stdout
    assert "wrote" in p.stdout or "matplotlib is not installed" in p.stdout
