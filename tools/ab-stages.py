#!/usr/bin/env python3
"""Compares two builds of the stages bench by running them at the same time, one per core.

    cargo bench --bench stages --no-run            # prints the bench binary's path
    tools/ab-stages.py OLD_BINARY NEW_BINARY [--rounds 6] [--only detect,density,relax-params,relax-world]

On a shared machine whose clock moves from one minute to the next, two builds taking turns
measure the host as much as the change (BENCHMARKS.md, "Seventh round"). Here both run at
once, each on one thread pinned to its own core (`taskset`), and they swap cores every round,
so that both see the same host. Two processes share the memory system, so each is slower than
it would be alone: read the two columns against each other, not against the goals.

Prints every round's µs per photon (per iteration) per core for each stage row of the bench,
then the medians.
"""

import argparse
import os
import statistics
import subprocess
import sys


def rows(text):
    """The bench table's rows: stage name → µs per photon (per iteration) per core."""
    out = {}
    stage = ""
    for line in text.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) < 4 or cells[0] in ("stage", "---"):
            continue
        # "of which …" rows belong to the stage above them (both relax stages have them).
        name = f"{stage}, {cells[0]}" if cells[0].startswith("of which") else cells[0]
        if not cells[0].startswith("of which"):
            stage = cells[0].split(" (")[0]
        try:
            out[name] = float(cells[3])
        except ValueError:
            pass
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("old", help="the stages bench binary to compare against")
    ap.add_argument("new", help="the stages bench binary to measure")
    ap.add_argument("--rounds", type=int, default=6)
    ap.add_argument("--only", default="detect,density,relax-params,relax-world",
                    help="PHOTONKIT_BENCH_ONLY for both runs")
    args = ap.parse_args()
    if (os.cpu_count() or 1) < 2:
        sys.exit("error: this needs two cores (one per build)")
    for b in (args.old, args.new):
        if not os.access(b, os.X_OK):
            sys.exit(f"error: {b}: not an executable bench binary")
    env = dict(os.environ, RAYON_NUM_THREADS="1", PHOTONKIT_BENCH_CLOCK="0", PHOTONKIT_BENCH_ONLY=args.only)
    results = {"old": [], "new": []}
    for r in range(args.rounds):
        cores = {"old": r % 2, "new": 1 - r % 2}
        procs = {
            name: subprocess.Popen(["taskset", "-c", str(cores[name]), binary, "--bench"], env=env,
                                   stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
            for name, binary in (("old", args.old), ("new", args.new))
        }
        for name, p in procs.items():
            out, _ = p.communicate()
            if p.returncode != 0:
                sys.exit(f"error: the {name} bench failed (exit {p.returncode})")
            results[name].append(rows(out))
        stages = list(results["old"][-1])
        print(f"round {r + 1}: " + "; ".join(
            f"{s}: {results['old'][-1][s]:.2f} → {results['new'][-1].get(s, float('nan')):.2f}" for s in stages))
    print("\nmedians (old → new, µs per photon (per iteration) per core):")
    for s in results["old"][0]:
        old = statistics.median(r[s] for r in results["old"] if s in r)
        new = statistics.median(r[s] for r in results["new"] if s in r)
        print(f"  {s}: {old:.2f} → {new:.2f} ({100 * (new / old - 1):+.0f} %)")


if __name__ == "__main__":
    main()
