#!/usr/bin/python3
"""Plot of `rsfm run --model patches` / `rsfm estimate --patches` (docs/patches.md).

Usage: plot_patch_run.py PATCH_NORMALS.csv OUT.png OUT.svg
Top: focal length (px) against frame. Bottom: each patch normal's angle (deg, log scale) to the
median normal of the live patches in that frame, both in the first camera's frame; one line per
patch. A flat scene (one floor) gives low, converging lines. Run with /usr/bin/python3 (Debian's
matplotlib) and MPLBACKEND=Agg.
"""
import csv
import sys
from collections import defaultdict

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def main():
    if len(sys.argv) != 4:
        sys.exit("usage: plot_patch_run.py PATCH_NORMALS.csv OUT.png OUT.svg")
    focal = {}
    angles = defaultdict(lambda: ([], []))
    with open(sys.argv[1], newline="") as f:
        for row in csv.DictReader(f):
            k = int(row["frame"])
            focal[k] = float(row["focal_px"])
            xs, ys = angles[int(row["patch"])]
            xs.append(k)
            ys.append(max(float(row["angle_to_median_deg"]), 1e-2))
    if not focal:
        sys.exit("plot_patch_run.py: no data rows in " + sys.argv[1])
    fig, (a0, a1) = plt.subplots(2, 1, figsize=(9, 7), sharex=True)
    ks = sorted(focal)
    a0.plot(ks, [focal[k] for k in ks], "-", color="tab:blue", lw=1.5)
    a0.set_ylabel("focal length (px)")
    a0.grid(True, alpha=0.3)
    for pid, (xs, ys) in sorted(angles.items()):
        a1.plot(xs, ys, "-", lw=0.8, alpha=0.7)
    a1.axhline(5.0, color="grey", lw=0.8, ls=":")
    a1.set_yscale("log")
    a1.set_ylabel("angle to the median normal (deg)")
    a1.set_xlabel("frame")
    a1.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(sys.argv[2], dpi=120)
    fig.savefig(sys.argv[3])


if __name__ == "__main__":
    main()
