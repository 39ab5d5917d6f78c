#!/usr/bin/env python3
"""Held photons and relaxed-set isotropy around a caustic's spot (docs/parameter-ball.md).

    tools/halo-stats.py held DETECTED.phm...   held share, all / halo, and how many held bases
                                               point radially; then per ring of distance
    tools/halo-stats.py relaxed RELAXED.phm... nearest-neighbour spread, λ2/λ1 of the 16
                                               nearest and major axis · radial, per band

The spot is the centre of the densest 0.1 m cell of the floor (x, y); the halo is every photon
more than 1 m from it. A photon is held when its factor |v_b| is below ½. Needs numpy; reads
PHM files with tools/phm.py.
"""

import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import phm  # noqa: E402


def load(path):
    """Every column of the PHM file at `path`, as numpy arrays (photon-major)."""
    with open(path, "rb") as f:
        f.seek(0, 2)
        size = f.tell()
        f.seek(0)
        _, _, _, meta_len, file_len = phm.read_preamble(f, size)
        meta = phm.parse_metadata(f.read(meta_len))
        n = phm.check_metadata(meta)
        out = {}
        for c in phm.check_columns(meta, n, meta_len, file_len):
            v = np.array(phm.read_column(f, c, False))
            out[c["name"]] = v.reshape(n, -1) if c["components"] > 1 else v
    return out


def spot_of(xy):
    """The centre of the densest 0.1 m cell."""
    cells, counts = np.unique(np.floor(xy / 0.1).astype(int), axis=0, return_counts=True)
    return (cells[counts.argmax()] + 0.5) * 0.1


def held(paths):
    rings = [0, 0.25, 0.5, 0.75, 1, 1.25, 1.5, 1.75, 2, 2.5, 3, 4, 6]
    for path in paths:
        d = load(path)
        xy = d["position"][:, :2]
        spot = spot_of(xy)
        r = np.linalg.norm(xy - spot, axis=1)
        radial = (xy - spot) / np.maximum(r, 1e-9)[:, None]
        is_held = np.linalg.norm(d["basis_v"], axis=1) < 0.5
        cos = np.abs((d["basis_u"][:, :2] * radial).sum(axis=1))
        halo = r > 1.0
        print(f"{path}: {len(r)} photons, spot ({spot[0]:.2f}, {spot[1]:.2f}), halo {halo.sum()}")
        print(f"  held: all {is_held.mean():.1%}, halo {is_held[halo].mean():.1%}; "
              f"held halo photons radial (|cos| > 0.9) {(cos[halo & is_held] > 0.9).mean():.1%}")
        for lo, hi in zip(rings[:-1], rings[1:]):
            m = (r >= lo) & (r < hi)
            if m.any():
                along = ((cos < 0.3) & is_held & m).sum() / max(1, (is_held & m).sum())
                print(f"  {lo:4.2f}-{hi:4.2f} m: {m.sum():5d} photons, {m.sum() / (np.pi * (hi * hi - lo * lo)):8.1f}/m², "
                      f"held {is_held[m].mean():6.1%}, of those along the ring (|cos| < 0.3) {along:6.1%}")


def band_stats(xy, spot, lo, hi, k=16):
    r = np.linalg.norm(xy - spot, axis=1)
    nn, ratio, cos = [], [], []
    for i in np.where((r >= lo) & (r < hi))[0]:
        d = np.linalg.norm(xy - xy[i], axis=1)
        d[i] = np.inf
        near = np.argpartition(d, k)[:k]
        nn.append(d[near].min())
        x = xy[near] - xy[near].mean(axis=0)
        w, v = np.linalg.eigh(x.T @ x)
        ratio.append(w[0] / w[1])
        cos.append(abs(v[:, 1] @ ((xy[i] - spot) / max(r[i], 1e-9))))
    nn = np.array(nn)
    return f"{len(nn)} photons, NN-distance CV {nn.std() / nn.mean():.3f}, λ2/λ1 {np.mean(ratio):.3f}, major·radial {np.mean(cos):.3f}"


def relaxed(paths):
    for path in paths:
        xy = load(path)["position"][:, :2]
        spot = spot_of(xy)
        print(f"{path}:")
        for lo, hi in [(1.0, 1.75), (1.75, 3.0)]:
            print(f"  {lo}-{hi} m: {band_stats(xy, spot, lo, hi)}")


if __name__ == "__main__":
    if len(sys.argv) < 3 or sys.argv[1] not in ("held", "relaxed"):
        sys.exit(__doc__)
    (held if sys.argv[1] == "held" else relaxed)(sys.argv[2:])
