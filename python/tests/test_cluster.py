"""The Kubernetes recipe in tools/cluster/ run here as the Job controller would run its pods
(tools/cluster/k8s-local.py, no cluster): the manifests pass Kubernetes' API schema, and the
Indexed Job's tiles merged give the map the untiled stage writes, byte for byte."""

import os
import subprocess
import sys

import pytest

from conftest import REPO, SAMPLES

kubernetes_validate = pytest.importorskip("kubernetes_validate")

CLUSTER = REPO / "tools" / "cluster"
MANIFESTS = [CLUSTER / "detect-k8s.yaml", CLUSTER / "detect-k8s-merge.yaml"]


def k8s_local(cli, data, *args):
    env = {**os.environ, "PATH": f"{cli.parent}{os.pathsep}{os.environ.get('PATH', '')}"}
    return subprocess.run(
        [sys.executable, str(CLUSTER / "k8s-local.py"), "--volume", f"photon-maps={data}", *map(str, args)],
        env=env,
        capture_output=True,
        text=True,
    )


def test_the_indexed_job_detects_tile_by_tile_what_the_whole_map_gives(cli, run_cli, tmp_path, reproducible):
    data = tmp_path / "data"
    (data / "parts").mkdir(parents=True)
    run_cli("trace", SAMPLES / "scenes" / "ring.toml", "--photons", "2e5", "-o", data / "map.phm")
    p = k8s_local(cli, data, "--validate", "1.29.0", *MANIFESTS)
    assert p.returncode == 0, p.stderr
    assert "photonkit-detect-tiles: 9 pod(s) completed" in p.stderr
    assert len(list((data / "parts").glob("part-*.phm"))) == 9
    run_cli("detect", data / "map.phm", "-o", tmp_path / "whole.phm")
    assert (data / "detected.phm").read_bytes() == (tmp_path / "whole.phm").read_bytes()


def test_the_manifests_need_kubernetes_1_28_for_a_retry_limit_per_index(cli, tmp_path):
    # backoffLimitPerIndex came in Kubernetes 1.28: the schema check tells versions apart.
    p = k8s_local(cli, tmp_path, "--validate", "1.27.0", MANIFESTS[0])
    assert p.returncode != 0
    assert "backoffLimitPerIndex" in p.stderr
