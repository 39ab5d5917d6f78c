#!/usr/bin/env python3
"""Runs `photonkit compare` for the record and writes the results into BENCHMARKS.md.

    tools/compare-report.py table1   # the paper's Table I: the point-lit prism at 20 M photons, 600x600, 4 spp
    tools/compare-report.py scenes   # every ground-truth scene, a photon-count sweep, equal-time tables

Each command replaces its own section of BENCHMARKS.md (between marker comments) and copies
the plots and image grids into docs/compare/ (SCENE-grid.png, SCENE-error-vs-time.png, table1-…). Options: --photons, --bin (default: builds and
uses target/release/photonkit), --cores (the machine's cores, for the per-core ratios).
"""

import argparse
import csv
import math
import os
import re
import shutil
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

# The paper's Table I (Spencer & Jones, the prism close-up, 7 cores): seconds.
PAPER_CORES = 7
PAPER = {
    "pm": {"trace": 12.3, "detect": None, "relax": None, "render": 4.3, "total": 14.8},
    "relax2009": {"trace": 12.3, "detect": 9.1, "relax": 27.3, "render": 4.3, "total": 48.2},
    "diffusion": {"trace": 12.3, "detect": 3.3, "relax": None, "render": 89.0, "total": 104.0},
    "ours": {"trace": 12.3, "detect": 5.3, "relax": 28.4, "render": 4.3, "total": 50.3},
    "ppm": {"trace": None, "detect": None, "relax": None, "render": None, "total": 2841.0},
}
LABELS = {
    "pm": "Standard PM",
    "relax2009": "Photon Relax.",
    "diffusion": "Diff-Based PM",
    "ours": "Our method",
    "ppm": "Progressive PM",
    "ours-progressive": "Ours, refined",
}
SCENES = ["glass-sphere", "water", "prism", "ring"]
SCENE_METHODS = "pm,relax2009,diffusion,ours,ppm,ours-progressive"


def binary(args):
    if args.bin:
        return args.bin
    subprocess.run(["cargo", "build", "--release", "--quiet"], cwd=ROOT, check=True)
    return os.path.join(ROOT, "target", "release", "photonkit")


def run_compare(bin_, argv):
    cmd = [bin_, "compare"] + argv
    print("+", " ".join(cmd), file=sys.stderr)
    t = time.time()
    subprocess.run(cmd, cwd=ROOT, check=True, stdout=subprocess.DEVNULL)
    return time.time() - t


def read_csv(path):
    with open(path, newline="") as f:
        # One line per method for the whole image (older reports have no region column).
        return [r for r in csv.DictReader(f) if r.get("region", "all") == "all"]


def fval(row, key):
    v = row.get(key, "")
    return float(v) if v not in ("", "NaN", "nan") else None


def replace_section(name, body):
    path = os.path.join(ROOT, "BENCHMARKS.md")
    text = open(path).read()
    begin, end = f"<!-- {name}:begin -->", f"<!-- {name}:end -->"
    block = f"{begin}\n{body.rstrip()}\n{end}"
    if begin in text and end in text:
        text = re.sub(re.escape(begin) + ".*?" + re.escape(end), lambda _: block, text, flags=re.S)
    else:
        text = text.rstrip() + "\n\n" + block + "\n"
    tmp = path + ".tmp"
    open(tmp, "w").write(text)
    os.replace(tmp, path)


def secs(x):
    if x is None:
        return "-"
    return f"{int(x // 60)}m {x % 60:.0f}s" if x >= 60 else f"{x:.2f} s"


def table1(args):
    bin_ = None if args.reuse else binary(args)
    out = os.path.join(ROOT, "target", "compare", "table1")
    argv = [
        f"samples/scenes/{args.scene}.toml", "--photons", args.photons, "--cells", "600", "--spp", "4", "--feature-spp", "4",
        "--ppm-passes", args.ppm_passes, "--seeds", args.seeds, "--out-dir", out,
    ]
    wall = 0.0 if args.reuse else run_compare(bin_, argv)
    rows = read_csv(os.path.join(out, "report.csv"))
    order = ["pm", "relax2009", "diffusion", "ours"]
    cols = [next(r for r in rows if r["method"] == m) for m in order]
    ppm = [r for r in rows if r["method"] == "ppm"]
    if ppm:
        cols.append(ppm[-1])
    n = args.cores
    stored = float(cols[0]["photons"])
    point = args.scene == "prism-point"
    view = (
        "the scene camera's perspective view of the fan (caustic radiance), against a progressive photon mapping "
        "reference of 64 passes of the same photon count, the scene having no closed form"
        if point else
        "the top-down orthographic view of the floor in irradiance mode, against the closed-form truth (see the "
        "scenes section), not the paper's perspective close-up"
    )
    scene_text = (
        f"The scene is `{args.scene}.toml`: the prism lit from behind by a point light (a 41° spot), as the "
        "paper's Fig. 6 and Table I are, " if point else f"The scene is `{args.scene}.toml`, "
    )
    intro = (
        f"`tools/compare-report.py table1` ran `photonkit compare {' '.join(argv)}` "
        f"({time.strftime('%Y-%m-%d')}, {n} cores{f', {wall:.0f} s wall in all' if wall else ''}). "
        + scene_text
        + f"which stores {stored / 1e3:.0f} k of the 20 M photons cast (the paper: 863 k). The image is 600×600 "
        f"with 4 samples per pixel like the paper's; errors are measured in {view}, over {args.seeds} seed(s). "
        "The per-photon rows divide by the photons stored. Each cell: our time, the paper's (7 cores), "
        f"and the per-core ratio (our seconds × {n} cores) / (paper seconds × {PAPER_CORES} cores): below 1, we "
        "spend fewer core-seconds."
    )
    lines = [
        "## Table I reproduction: the prism at the paper's sizes",
        "",
        intro,
        "",
        "| | " + " | ".join(LABELS[c["method"]] + (f" ({c['setting']})" if c["method"] == "ppm" else "") for c in cols) + " |",
        "|---|" + "---|" * len(cols),
    ]

    def cell(c, key):
        ours = fval(c, f"{key}_s")
        paper = PAPER[c["method"]][key]
        if ours is None:
            return "-"
        if paper is None or c["method"] == "ppm":
            return secs(ours)
        return f"{secs(ours)} ({secs(paper)}; ×{ours * n / (paper * PAPER_CORES):.3f})"

    def count(x):
        x = int(x)
        return "-" if x == 0 else (f"{x / 1e6:.3g}M" if x >= 1e6 else f"{x / 1e3:.0f}k")

    lines.append("| M / absorbed M | " + " | ".join(f"{count(c['emitted'])} / {count(c['photons'])}" for c in cols) + " |")
    lines.append("| (paper) | " + " | ".join("4.6B / 200M" if c["method"] == "ppm" else "20M / 863k" for c in cols) + " |")
    for key, name in [("trace", "Photon cast t"), ("detect", "Feature detect t"), ("relax", "Relaxation t"),
                      ("render", "Render t"), ("total", "Total t")]:
        lines.append(f"| {name} | " + " | ".join(cell(c, key) for c in cols) + " |")
    # Our map absorbs far more of the 20 M photons than the paper's close-up did (863 k), so the
    # per-stage ratios above mix speed and photon count: these rows divide by the photons.
    def per_photon(c, key, iterations):
        ours, paper = fval(c, f"{key}_s"), PAPER[c["method"]][key]
        if ours is None or paper is None or c["method"] == "ppm":
            return "-"
        o = ours * n / (float(c["photons"]) * iterations) * 1e6
        p = paper * PAPER_CORES / (863e3 * iterations) * 1e6
        return f"{o:.2f} µs ({p:.2f} µs; ×{o / p:.3f})"
    its = {"relax2009": 14, "ours": 14}
    lines.append("| detect, core-µs per absorbed photon | " + " | ".join(per_photon(c, "detect", 1) for c in cols) + " |")
    lines.append("| relax, core-µs per photon-iteration | " + " | ".join(
        per_photon(c, "relax", its.get(c["method"], 1)) for c in cols) + " |")
    lines.append("| render, core-µs per image sample (600²·4) | " + " | ".join(
        "-" if fval(c, "render_s") is None or c["method"] == "ppm" else
        f"{fval(c, 'render_s') * n / 1.44e6 * 1e6:.2f} µs ({PAPER[c['method']]['render'] * PAPER_CORES / 1.44e6 * 1e6:.2f} µs)"
        for c in cols) + " |")
    for key, name in [("nrmse", "NRMSE"), ("rel_mse", "relative MSE"), ("ssim", "SSIM"),
                      ("edge_nrmse", "edge-band NRMSE"), ("overlap_nrmse", "overlap NRMSE")]:
        lines.append(f"| {name} | " + " | ".join(
            "-" if fval(c, key) is None or fval(c, key) != fval(c, key) else f"{fval(c, key):.4f}" for c in cols) + " |")
    os.makedirs(os.path.join(ROOT, "docs", "compare"), exist_ok=True)
    for f in ["grid.png", "error-vs-time.png"]:
        shutil.copy(os.path.join(out, f), os.path.join(ROOT, "docs", "compare", f"table1-{f}"))
    lines += ["", "Images and error maps: docs/compare/table1-grid.png; error against time: "
              "docs/compare/table1-error-vs-time.png."]
    replace_section("table1", "\n".join(lines))


def equal_time(rows):
    """The equal-time table (as report.rs's equal_time_markdown) from a report.csv."""
    order = ["pm", "relax2009", "diffusion", "ppm"]
    pts = {m: [(fval(r, "total_s"), fval(r, "nrmse")) for r in rows if r["method"] == m] for m in order}
    others = [m for m in order if pts[m]]

    def interp(p, t):
        p = sorted((x, y) for x, y in p if x and y and x > 0 and y > 0)
        for x, y in p:
            if abs(x / t - 1) < 1e-9:
                return y
        for i, (x, y) in enumerate(p):
            if x > t:
                if i == 0:
                    return None
                (x0, y0), (x1, y1) = p[i - 1], p[i]
                f = (math.log(t) - math.log(x0)) / (math.log(x1) - math.log(x0))
                return math.exp(math.log(y0) + f * (math.log(y1) - math.log(y0)))
        return None

    out = ["| run | our time | our NRMSE | " + " | ".join(LABELS[m] for m in others) + " |",
           "|---|---|---|" + "---|" * len(others)]
    for r in rows:
        if r["method"] != "ours":
            continue
        t, e = fval(r, "total_s"), fval(r, "nrmse")
        cells = []
        for m in others:
            within = [(x, y) for x, y in pts[m] if x <= t * (1 + 1e-9)]
            best = min(within, key=lambda q: q[1]) if within else None
            i = interp(pts[m], t)
            parts = []
            if best:
                parts.append(f"best {best[1]:.4f} ({best[1] / e:.2f}×, {secs(best[0])})")
            if i is not None:
                parts.append(f"at our time {i:.4f} ({i / e:.2f}×)")
            cells.append("; ".join(parts) if parts else "every run slower")
        out.append(f"| {r['run']} | {secs(t)} | {e:.4f} | " + " | ".join(cells) + " |")
    return "\n".join(out)


def read_all(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def scenes(args):
    """Every scene's compare run at one photon count with compare's defaults (4 seeds, 16 jittered
    samples per cell and 4096 in the core and edge cells, standard PM at K = 15, 50, 200, PPM with a local initial radius)
    and every method, our refined map included, one table per scene: each method's mean time and, per region, its NRMSE with the split into bias² and
    variance over the seeds."""
    bin_ = None if args.reuse else binary(args)
    lines = [
        f"`tools/compare-report.py scenes` ({time.strftime('%Y-%m-%d')}, {args.cores} cores) ran, for each scene, "
        f"`photonkit compare samples/scenes/SCENE.toml --photons {args.photons_scenes}` with the defaults: 4 seeds, "
        "16 jittered samples per cell and 4096 in the core and edge cells (each pixel its cell's mean, as the truth "
        "is; docs/truth.md, \"Sampling\"; PPM at most 256 a pass, diffusion-based PM at most 1024; these renders "
        "are untimed, a method's time counts its render at 16), standard PM at K = 15, 50 "
        "and 200, progressive PM (PPM) at 1, 4 and 16 passes of as many photons with its initial radius the "
        "30-NN distance of its first pass, α = 2/3, and our map refined (`--methods …,ours-progressive`) "
        "at 1, 4 and 16 passes of as many photons. Times are means over the seeds (the whole method: trace, "
        "detect, relax, render). Each cell: NRMSE over the whole truth's mean, and its split "
        "(bias², variance) across the seeds, NRMSE² = bias² + variance; regions as docs/truth.md defines them "
        "(a region the truth lacks is '-'). Each scene's report.md (in target/compare/SCENE) adds the time "
        "to reach 10 %, 5 % and 2 % relative error per region, and the median and 90th-percentile "
        "relative errors.",
    ]
    for s in SCENES:
        out = os.path.join(ROOT, "target", "compare", s)
        if not args.reuse:
            run_compare(bin_, [f"samples/scenes/{s}.toml", "--photons", args.photons_scenes, "--methods", SCENE_METHODS,
                               "--out-dir", out])
        rows = read_all(os.path.join(out, "report.csv"))
        md = open(os.path.join(out, "report.md")).read()
        cells = re.search(r"core (\d+) pixels.*?edge (\d+), smooth (\d+), dark (\d+)", md, flags=re.S)
        lines += ["", f"### {s}", ""]
        if cells:
            lines += [f"Pixels per region: core {cells.group(1)}, edge {cells.group(2)}, smooth {cells.group(3)}, "
                      f"dark {cells.group(4)}.", ""]
        os.makedirs(os.path.join(ROOT, "docs", "compare"), exist_ok=True)
        for f in ["grid.png", "error-vs-time.png"]:
            shutil.copy(os.path.join(out, f), os.path.join(ROOT, "docs", "compare", f"{s}-{f}"))
        lines += [f"Images and error maps: docs/compare/{s}-grid.png; error against time per region: "
                  f"docs/compare/{s}-error-vs-time.png.", ""]
        lines += ["| method | setting | time | all | core | edge | smooth | dark |", "|---|---|---|---|---|---|---|---|"]
        keys = []
        for r in rows:
            k = (r["method"], r["setting"])
            if k not in keys:
                keys.append(k)

        def cell(r):
            e = fval(r, "nrmse")
            if e is None or int(r["cells"]) == 0:
                return "-"
            b, v = fval(r, "bias2"), fval(r, "variance")
            split = f" ({b:.1e}, {v:.1e})" if b is not None and v is not None else ""
            return f"{e:.4f}{split}"

        for m, setting in keys:
            by = {r["region"]: r for r in rows if r["method"] == m and r["setting"] == setting}
            t = fval(by["all"], "total_s")
            short = setting.replace(", α = 2/3", "").replace("r₁ = 30-NN distance", "local r₁")
            lines.append(f"| {LABELS[m]} | {short} | {secs(t)} | " +
                         " | ".join(cell(by[g]) for g in ["all", "core", "edge", "smooth", "dark"]) + " |")
    replace_section("scenes", "\n".join(lines))


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("what", choices=["table1", "scenes"])
    p.add_argument("--bin", help="photonkit binary (default: cargo build --release)")
    p.add_argument("--cores", type=int, default=os.cpu_count())
    p.add_argument("--photons", default="2e7", help="table1: photons emitted (the paper: 20 M)")
    p.add_argument("--scene", default="prism-point", help="table1: sample scene (the paper's: prism-point)")
    p.add_argument("--seeds", default="1", help="table1: seeds per method")
    p.add_argument("--ppm-passes", default=None)
    p.add_argument("--ppm-photons", default="1e6", help="scenes: photons per progressive pass")
    p.add_argument("--photons-scenes", default="1e6", help="scenes: photons emitted per map (and per PPM pass)")
    p.add_argument("--reuse", action="store_true", help="rewrite the section from the last run's CSV, no new run")
    a = p.parse_args()
    if a.what == "table1":
        a.ppm_passes = a.ppm_passes or "1,4"
        table1(a)
    else:
        a.ppm_passes = a.ppm_passes or "1,4,16,64"
        scenes(a)


if __name__ == "__main__":
    main()
