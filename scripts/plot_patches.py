#!/usr/bin/python3
"""Normal and beta errors against frame of `rsfm experiment patches`.

Usage: plot_patches.py PATCHES_DATA.csv OUT.png OUT.svg
One column per scene (sphere, plane). Top: normal error (deg, log scale): for the patch filter the
mean over patches of each patch normal's error, for the point filter on the patch centres the
plane fitted to its points (plane scene only). Bottom: beta error (%). Colour = measurement
(exact, instantaneous, point-centres), line style = noise level. Means over successful trials.
Run with /usr/bin/python3 (Debian's matplotlib) and MPLBACKEND=Agg.
"""
import csv
import math
import sys
from collections import defaultdict

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def num(s):
    try:
        v = float(s)
    except ValueError:
        return math.nan
    return v


def main():
    if len(sys.argv) != 4:
        sys.exit("usage: plot_patches.py PATCHES_DATA.csv OUT.png OUT.svg")
    series = defaultdict(lambda: {"frame": [], "normal": [], "beta": []})
    with open(sys.argv[1], newline="") as f:
        for row in csv.DictReader(f):
            s = series[(row["scene"], row["measurement"], num(row["noise"]))]
            s["frame"].append(int(row["frame"]))
            s["normal"].append(num(row["normal_err_deg"]))
            s["beta"].append(num(row["beta_err_pct"]))
    if not series:
        sys.exit("plot_patches.py: no data rows in " + sys.argv[1])
    scenes = [s for s in ("sphere", "plane") if any(k[0] == s for k in series)]
    fig, axes = plt.subplots(2, len(scenes), figsize=(6 * len(scenes), 7.5), squeeze=False)
    colours = {"exact": "tab:blue", "instantaneous": "tab:orange", "point-centres": "tab:green"}
    styles = ["-", "--", ":", "-."]
    for col, scene in enumerate(scenes):
        noises = sorted({k[2] for k in series if k[0] == scene})
        for (sc, meas, noise), s in sorted(series.items()):
            if sc != scene:
                continue
            style = styles[noises.index(noise) % len(styles)]
            label = f"{meas}, rho {noise:g}"
            normal = [max(v, 1e-3) if not math.isnan(v) else math.nan for v in s["normal"]]
            if not all(math.isnan(v) for v in normal):
                axes[0][col].plot(s["frame"], normal, style, color=colours.get(meas, "k"), lw=1.3, label=label)
            axes[1][col].plot(s["frame"], [max(v, 1e-3) for v in s["beta"]], style, color=colours.get(meas, "k"),
                              lw=1.3, label=label)
        axes[0][col].set_title(f"{scene} scene")
        axes[0][col].set_ylabel("normal error (deg)")
        axes[1][col].set_ylabel("beta error (%)")
        axes[1][col].set_xlabel("frame")
        for r in (0, 1):
            axes[r][col].set_yscale("log")
            axes[r][col].grid(True, which="both", alpha=0.3)
        axes[0][col].axhline(5.0, color="grey", lw=0.8, ls=":")
        axes[1][col].axhline(5.0, color="grey", lw=0.8, ls=":")
        axes[0][col].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(sys.argv[2], dpi=120)
    fig.savefig(sys.argv[3])


if __name__ == "__main__":
    main()
