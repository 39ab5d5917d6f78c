#!/usr/bin/env python3
"""The caustic of the glass sphere, traced, relaxed and rendered from Python, and its radial
profile: the floor's irradiance against the distance from the focus, from the photons as
traced and as relaxed.

    pip install ./python matplotlib        # from the repository's root
    python3 docs/examples/radial_profile.py [--photons 1e6] [--out radial-profile.png]

Without matplotlib it prints the profile as a table instead of plotting it.
"""

import argparse
import logging

import numpy as np

import photonkit


def radial_profile(image, extent_m, bins):
    """Mean pixel value per ring around the image's centre: (ring radii in metres, means)."""
    h, w, _ = image.shape
    y, x = np.mgrid[0:h, 0:w]
    metres_per_pixel = extent_m / w
    r = np.hypot(x - (w - 1) / 2, y - (h - 1) / 2) * metres_per_pixel
    luminance = image @ np.array([0.2126, 0.7152, 0.0722], dtype=np.float32)
    edges = np.linspace(0, extent_m / 2, bins + 1)
    which = np.digitize(r.ravel(), edges) - 1
    inside = which < bins
    total = np.bincount(which[inside], luminance.ravel()[inside], minlength=bins)
    count = np.bincount(which[inside], minlength=bins)
    return (edges[:-1] + edges[1:]) / 2, total / np.maximum(count, 1)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--photons", type=float, default=1e6, help="photons to emit (default 1e6)")
    parser.add_argument("--extent", type=float, default=1.2, help="side of the floor square viewed, metres")
    parser.add_argument("--pixels", type=int, default=300, help="image side in pixels")
    parser.add_argument("--out", default="radial-profile.png", help="the plot to write")
    args = parser.parse_args()
    logging.basicConfig(format="%(name)s: %(message)s")
    logging.getLogger("photonkit").setLevel(logging.INFO)  # the stages' notes, as the CLI prints them

    # Trace the embedded default scene (a glass sphere above a floor, lit from above), then
    # detect → relax → collapse → relax, all in memory.
    traced = photonkit.trace(photons=args.photons)
    relaxed = photonkit.pipeline(traced)
    print(f"{len(traced)} photons stored; relaxed in {len(relaxed.history) - 1} stages")

    # The floor seen from straight above, irradiance in W/m²: a scene-less view of the plane
    # z = 0, each pixel a floor cell.
    half = args.extent / 2
    view = dict(plane="z=0", rect=(-half, -half, half, half), width=args.pixels, k=15)
    profiles = {
        "traced": radial_profile(photonkit.render(traced, **view), args.extent, 60),
        "relaxed": radial_profile(photonkit.render(relaxed, **view), args.extent, 60),
    }

    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib is not installed (pip install matplotlib): the profile as a table")
        r, traced_e = profiles["traced"]
        _, relaxed_e = profiles["relaxed"]
        print(f"{'r (m)':>8} {'traced (W/m²)':>14} {'relaxed (W/m²)':>15}")
        for row in zip(r, traced_e, relaxed_e):
            print(f"{row[0]:8.3f} {row[1]:14.4f} {row[2]:15.4f}")
        return
    fig, ax = plt.subplots(figsize=(6, 4))
    for label, (r, e) in profiles.items():
        ax.plot(r * 100, e, label=label)
    ax.set_xlabel("distance from the sphere's axis (cm)")
    ax.set_yscale("log")
    ax.set_ylabel("floor irradiance (W/m², luminance)")
    ax.set_title(f"Glass sphere caustic, {len(traced):,} photons")
    ax.legend()
    fig.tight_layout()
    fig.savefig(args.out, dpi=120)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
