"""Each stage called from Python writes the file the command line writes (byte for byte, with
SOURCE_DATE_EPOCH set for both), and a map kept in memory is the same map."""

import filecmp
import threading
import time

import numpy as np
import photonkit
import pytest

from conftest import SAMPLES

PHOTONS = 20_000


def same(a, b):
    return filecmp.cmp(a, b, shallow=False)


def exr_parts(path):
    """An OpenEXR file as (its header's attributes as a dict, every byte after the header).
    The header's attributes are compared as a set: their order in a file varies from run to run
    of the command line itself (the exr crate keeps them in a hash map)."""
    data = path.read_bytes()
    assert data[:4] == b"\x76\x2f\x31\x01", "not an OpenEXR file"
    at, attributes = 8, {}
    while data[at] != 0:
        name_end = data.index(b"\0", at)
        type_end = data.index(b"\0", name_end + 1)
        size = int.from_bytes(data[type_end + 1 : type_end + 5], "little")
        value_at = type_end + 5
        attributes[data[at:name_end]] = (data[name_end + 1 : type_end], data[value_at : value_at + size])
        at = value_at + size
    return attributes, data[at:]


@pytest.fixture
def traced(tmp_path, run_cli, reproducible):
    """A map traced by the command line from the embedded default scene."""
    run_cli("trace", "--photons", PHOTONS, "-o", "cli-traced.phm")
    return tmp_path / "cli-traced.phm"


def test_trace_writes_the_file_the_command_line_writes(tmp_path, traced, run_cli):
    m = photonkit.trace(photons=PHOTONS, output=tmp_path / "py-traced.phm")
    assert same(traced, tmp_path / "py-traced.phm")
    assert m.path == str(tmp_path / "py-traced.phm") and len(m) > 1000
    # Kept in memory, then written: the same file again.
    photonkit.trace(photons=float(PHOTONS)).write(tmp_path / "memory.phm")
    assert same(traced, tmp_path / "memory.phm")


def test_trace_of_a_scene_file_with_options(tmp_path, run_cli, reproducible):
    scene = SAMPLES / "scenes" / "prism.toml"
    args = dict(stored=3000, seed=7, store="direct", max_bounces=8)
    run_cli("trace", scene, "--stored", 3000, "--seed", 7, "--store", "direct", "--max-bounces", 8, "-o", "cli.phm")
    photonkit.trace(scene, tmp_path / "py.phm", **args)
    assert same(tmp_path / "cli.phm", tmp_path / "py.phm")
    run_cli("trace", scene, "--photons", 4000, "--shard", "1/3", "-o", "cli-shard.phm")
    photonkit.trace(str(scene), str(tmp_path / "py-shard.phm"), photons=4000, shard="1/3", threads=1)
    assert same(tmp_path / "cli-shard.phm", tmp_path / "py-shard.phm")


def test_trace_of_a_gltf_scene_warns_of_what_it_does_not_honour(tmp_path, caplog):
    """A glTF scene traces from Python as from the command line, and what the file holds that the
    tracer does not honour (an emissive material) comes as one UserWarning naming it."""
    import json
    import logging
    import shutil

    gltf = json.loads((SAMPLES / "scenes" / "gltf" / "reflector.gltf").read_text())
    gltf["materials"][0]["emissiveFactor"] = [1.0, 1.0, 1.0]
    scene = tmp_path / "glowing.gltf"
    scene.write_text(json.dumps(gltf))
    with pytest.warns(UserWarning, match="emissiveFactor"):
        m = photonkit.trace(scene, photons=2000)
    assert len(m) > 0
    # The sample itself: no warning.
    shutil.copy(SAMPLES / "scenes" / "gltf" / "reflector.gltf", tmp_path / "plain.gltf")
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with caplog.at_level(logging.INFO, logger="photonkit"):
            photonkit.trace(tmp_path / "plain.gltf", photons=2000)


def test_detect_relax_collapse_write_the_command_lines_files(tmp_path, traced, run_cli):
    cli = lambda *a: run_cli(*a)  # noqa: E731
    cli("detect", traced, "-o", "cli-detected.phm", "--kc", 30, "--beta", 2.5, "--growths", 1)
    cli("relax", "cli-detected.phm", "-o", "cli-relaxed.phm", "-R", 3, "--kf", 12, "--step-limit", 0.4)
    cli("collapse", "cli-relaxed.phm", "-o", "cli-collapsed.phm")
    cli("relax", "cli-collapsed.phm", "-o", "cli-final.phm", "-R", 2)

    d = photonkit.detect(traced, tmp_path / "py-detected.phm", kc=30, beta=2.5, growths=1)
    r = photonkit.relax(d, tmp_path / "py-relaxed.phm", iterations=3, kf=12, step_limit=0.4)
    c = photonkit.collapse(r, tmp_path / "py-collapsed.phm")
    photonkit.relax(c, tmp_path / "py-final.phm", iterations=2)
    for stage in ["detected", "relaxed", "collapsed", "final"]:
        assert same(tmp_path / f"cli-{stage}.phm", tmp_path / f"py-{stage}.phm"), stage

    # The same chain in memory (each map named after the file it started from), written at the end.
    m = photonkit.open(traced)
    m = photonkit.detect(m, kc=30, beta=2.5, growths=1)
    m = photonkit.relax(m, iterations=3, kf=12, step_limit=0.4)
    m = photonkit.relax(photonkit.collapse(m), iterations=2)
    assert m.path is None
    m.write(tmp_path / "memory-final.phm")
    assert same(tmp_path / "cli-final.phm", tmp_path / "memory-final.phm")


def test_detect_with_the_other_methods(tmp_path, traced, run_cli):
    run_cli("detect", traced, "-o", "cli.phm", "--method", "gradient", "--gain", 0.8, "--mu-sigma", "paper")
    photonkit.detect(traced, tmp_path / "py.phm", method="gradient", gain=0.8, mu_sigma="paper")
    assert same(tmp_path / "cli.phm", tmp_path / "py.phm")


def test_pipeline_writes_the_maps_photonkit_pipeline_writes(tmp_path, run_cli, reproducible):
    run_cli("pipeline", "--photons", PHOTONS, "-R", 2, "--kc", 30, "--out-dir", "cli", "--", "--width", 16)
    (tmp_path / "py").mkdir()
    traced = photonkit.trace(photons=PHOTONS, output=tmp_path / "py" / "traced.phm")
    relaxed = photonkit.pipeline(traced, tmp_path / "py", iterations=2, kc=30)
    assert relaxed.path == str(tmp_path / "py" / "relaxed.phm")
    for name in ["traced", "detected", "relaxed-params", "collapsed", "relaxed"]:
        assert same(tmp_path / "cli" / f"{name}.phm", tmp_path / "py" / f"{name}.phm"), name
    in_memory = photonkit.pipeline(traced, iterations=2, kc=30)
    assert in_memory.path is None
    assert in_memory["position"].tobytes() == relaxed["position"].tobytes()


def test_render_writes_the_command_lines_images(tmp_path, traced, run_cli):
    args = ["--width", 48, "--height", 32, "--spp", 1, "-k", 10, "--exposure", 1]
    run_cli("render", traced, "-o", "cli.exr", *args)
    image = photonkit.render(traced, tmp_path / "py.exr", width=48, height=32, spp=1, k=10, exposure=1)
    assert exr_parts(tmp_path / "cli.exr") == exr_parts(tmp_path / "py.exr")
    assert same(tmp_path / "cli.png", tmp_path / "py.png")
    assert image.shape == (32, 48, 3) and image.dtype == np.float32
    assert np.isfinite(image).all() and image.max() > 0
    # Without an output nothing is written, and the pixels are the same.
    again = photonkit.render(photonkit.open(traced), width=48, height=32, spp=1, k=10)
    assert np.array_equal(image, again)
    # A scene-less view of the floor: irradiance, W/m².
    top = photonkit.render(traced, plane="z=0", rect=(-1, -1, 1, 1), width=20)
    assert top.shape == (20, 20, 3)
    run_cli("render", traced, "-o", "plane.exr", "--plane", "z=0", "--rect=-1,-1,1,1", "--width", 20, "--no-png")
    photonkit.render(traced, tmp_path / "py-plane.exr", plane="z=0", rect=(-1, -1, 1, 1), width=20, no_png=True)
    assert exr_parts(tmp_path / "plane.exr") == exr_parts(tmp_path / "py-plane.exr")
    assert not (tmp_path / "py-plane.png").exists()


def test_render_of_a_grown_map_gathers_as_the_command_line_does(tmp_path, traced, run_cli):
    # A map refined with growth: without k both render within the distance of the 15th nearest
    # of its first photons; k=15 asks for the plain k-NN estimate, another image.
    run_cli("detect", traced, "-o", "d.phm")
    run_cli("relax", "d.phm", "-o", "r.phm")
    run_cli("collapse", "r.phm", "-o", "c.phm")
    run_cli("relax", "c.phm", "-o", "rr.phm")
    run_cli("refine", "rr.phm", "-o", "grown.phm", "--passes", 4)
    grown = tmp_path / "grown.phm"
    assert len(photonkit.open(grown)) > len(photonkit.open(tmp_path / "rr.phm"))
    args = ["--width", 48, "--height", 32, "--spp", 1, "--no-png"]
    run_cli("render", grown, "-o", "cli.exr", *args)
    photonkit.render(grown, tmp_path / "py.exr", width=48, height=32, spp=1, no_png=True)
    assert exr_parts(tmp_path / "cli.exr") == exr_parts(tmp_path / "py.exr")
    knn = photonkit.render(grown, width=48, height=32, spp=1, k=15)
    local = photonkit.render(grown, width=48, height=32, spp=1)
    assert not np.array_equal(knn, local)


def test_stages_release_the_interpreter(traced):
    """Python threads run while a stage does: a counter in this thread advances meanwhile."""
    m = photonkit.detect(traced)
    done = threading.Event()
    ticks = 0

    def stage():
        photonkit.relax(m, iterations=10)
        done.set()

    t = threading.Thread(target=stage)
    start = time.perf_counter()
    t.start()
    while not done.is_set():
        ticks += 1
    t.join()
    seconds = time.perf_counter() - start
    assert seconds > 0.05, "the stage was too short to tell"
    assert ticks > 10_000 * seconds, f"{ticks} ticks in {seconds:.2f} s: the stage held the interpreter"


def test_compare_reports_every_method_against_the_truth(tmp_path):
    result = photonkit.compare(
        out_dir=tmp_path / "cmp", photons=20_000, methods=["pm", "ours"], pm_k=[15], seeds=1, cells=16, spp=1,
        fast_truth=True, iterations=2,
    )
    assert (tmp_path / "cmp" / "report.md").is_file() and result["report"] == str(tmp_path / "cmp" / "report.md")
    rows = result["rows"]
    assert {r["method"] for r in rows} == {"pm", "ours"}
    whole = [r for r in rows if r["region"] == "all"]
    assert all(r["nrmse"] > 0 and r["photons"] > 0 for r in whole)
    assert "Our method" in result["table"]


def resident_bytes():
    """This process's resident set now (Linux), which a memory budget must leave room for."""
    with open("/proc/self/status") as status:
        kb = next(int(line.split()[1]) for line in status if line.startswith("VmRSS:"))
    return kb * 1024


def test_a_memory_budget_tiles_detect_relax_and_render_into_the_same_results(tmp_path, reproducible, caplog):
    """`memory=` chooses a tiling as `--memory` does; the tiled maps and image are the whole
    map's, byte for byte; a budget no tiling meets is a ValueError naming what it needs."""
    import logging

    traced = photonkit.trace(stored=40_000, output=tmp_path / "traced.phm")
    n = len(traced)
    whole = photonkit.detect(traced, kc=30)
    # detect holds 72 B per photon of the map, and 200 B per photon of a tile's working set
    # (3 times the tile): room for a third of that over the process's own resident set.
    budget = resident_bytes() + 72 * n + 200 * n
    with caplog.at_level(logging.INFO, logger="photonkit"):
        tiled = photonkit.detect(traced, kc=30, memory=budget)
    assert any("detecting in" in r.getMessage() and "tiles" in r.getMessage() for r in caplog.records)
    for column in ["basis_u", "basis_v", "lambda2", "r_param"]:
        assert tiled[column].tobytes() == whole[column].tobytes(), column

    relaxed = photonkit.relax(whole, iterations=2)
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="photonkit"):
        relaxed_tiled = photonkit.relax(whole, iterations=2, memory=resident_bytes() + 72 * n + 200 * n)
    assert any("relaxing in" in r.getMessage() for r in caplog.records)
    assert relaxed_tiled["position"].tobytes() == relaxed["position"].tobytes()

    image = photonkit.render(relaxed, width=48, height=32, spp=1)
    # The least budget the render takes, as its refusal of a smaller one states it.
    with pytest.raises(ValueError, match="needs at least") as refused:
        photonkit.render(relaxed, width=48, height=32, spp=1, memory="1M")
    least = int(str(refused.value).rsplit(" ", 1)[1])
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="photonkit"):
        streamed = photonkit.render(relaxed, width=48, height=32, spp=1, memory=least + (256 << 10))
    assert any("streamed the map" in r.getMessage() for r in caplog.records)
    assert streamed.tobytes() == image.tobytes()

    for stage in [
        lambda: photonkit.detect(traced, memory="1M"),
        lambda: photonkit.relax(whole, memory="1M"),
    ]:
        with pytest.raises(ValueError, match="at least"):
            stage()
    with pytest.raises(ValueError, match="plane"):
        photonkit.render(relaxed, plane="y=0", memory="1G")
