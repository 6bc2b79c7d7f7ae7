#!/usr/bin/python3
"""Error against frame for each method of `rsfm experiment planes`.

Usage: plot_planes.py PLANES_DATA.csv OUT.png OUT.svg
Top row: mean normal error (deg, log scale); bottom row: RMS translation error; one column per
noise level. Run with /usr/bin/python3 (Debian's matplotlib) and MPLBACKEND=Agg.
"""
import csv
import sys
from collections import defaultdict

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

STYLE = {
    "point": ("tab:orange", "-"),
    "plane-per-face": ("tab:green", "-"),
    "planes-rigid": ("tab:blue", "-"),
    "planes-rigid-iekf": ("tab:purple", "--"),
    "batch": ("black", ":"),
}


def main():
    if len(sys.argv) != 4:
        sys.exit("usage: plot_planes.py PLANES_DATA.csv OUT.png OUT.svg")
    data = defaultdict(lambda: defaultdict(list))
    with open(sys.argv[1], newline="") as f:
        for row in csv.DictReader(f):
            d = data[(row["method"], float(row["noise_px"]))]
            for k in ("frame", "normal_err_deg", "t_err"):
                d[k].append(float(row[k]))
    if not data:
        sys.exit("plot_planes.py: no data rows in " + sys.argv[1])
    noises = sorted({n for _, n in data})
    fig, axes = plt.subplots(2, len(noises), figsize=(4.4 * len(noises), 7.5), sharex=True, squeeze=False)
    for c, noise in enumerate(noises):
        for method, (colour, style) in STYLE.items():
            d = data.get((method, noise))
            if not d:
                continue
            frames = d["frame"]
            axes[0][c].plot(frames[1:], [max(v, 1e-3) for v in d["normal_err_deg"][1:]], style,
                            color=colour, lw=1.4, label=method)
            axes[1][c].plot(frames, d["t_err"], style, color=colour, lw=1.4, label=method)
        axes[0][c].set_title(f"noise {noise:g} px")
        axes[0][c].set_yscale("log")
        axes[1][c].set_xlabel("frame")
        for r in range(2):
            axes[r][c].grid(alpha=0.3)
    axes[0][0].set_ylabel("normal error (deg), mean over faces")
    axes[1][0].set_ylabel("translation error, RMS over trials")
    axes[0][-1].legend(fontsize=8)
    fig.suptitle("Box scene: error against frame", fontsize=11)
    fig.tight_layout()
    fig.savefig(sys.argv[2], dpi=110)
    fig.savefig(sys.argv[3])


if __name__ == "__main__":
    main()
