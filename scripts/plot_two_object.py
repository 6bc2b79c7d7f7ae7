#!/usr/bin/python3
"""Errors against frame of `rsfm experiment two-object`.

Usage: plot_two_object.py TWO_OBJECT_DATA.csv OUT.png OUT.svg
Panels: rotation error (deg), translation error (scene units), plane normal error (deg, log
scale) of both objects (object 0 solid, object 1 dashed; one colour per noise level), and the
shared beta's error (%). Means over successful trials. Run with /usr/bin/python3 (Debian's
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
        sys.exit("usage: plot_two_object.py TWO_OBJECT_DATA.csv OUT.png OUT.svg")
    data = defaultdict(lambda: defaultdict(list))
    with open(sys.argv[1], newline="") as f:
        for row in csv.DictReader(f):
            d = data[float(row["noise_px"])]
            for k, v in row.items():
                if k != "noise_px":
                    d[k].append(float(v))
    if not data:
        sys.exit("plot_two_object.py: no data rows in " + sys.argv[1])
    fig, axes = plt.subplots(2, 2, figsize=(10, 7.5), sharex=True)
    panels = [
        (axes[0][0], "rot_err_deg", "rotation error (deg)", False),
        (axes[0][1], "t_err", "translation error (scene units)", False),
        (axes[1][0], "normal_err_deg", "normal error (deg)", True),
    ]
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for c, noise in enumerate(sorted(data)):
        d = data[noise]
        colour = colours[c % len(colours)]
        for ax, key, _, log in panels:
            for j, style in ((0, "-"), (1, "--")):
                ys = d[f"{key}_{j}"]
                if log:
                    ys = [max(v, 1e-3) for v in ys]
                ax.plot(d["frame"], ys, style, color=colour, lw=1.3, label=f"{noise:g} px, object {j}")
        axes[1][1].plot(d["frame"], [max(v, 1e-3) for v in d["beta_err_pct"]], "-", color=colour, lw=1.3, label=f"{noise:g} px")
    for ax, _, title, log in panels:
        ax.set_ylabel(title)
        if log:
            ax.set_yscale("log")
    axes[1][1].set_ylabel("beta error (%), shared")
    axes[1][1].set_yscale("log")
    for ax in axes[1]:
        ax.set_xlabel("frame")
    for row in axes:
        for ax in row:
            ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=7)
    axes[1][1].legend(fontsize=8)
    fig.suptitle("Two independently moving planes: errors against frame (mean over trials)", fontsize=11)
    fig.tight_layout()
    fig.savefig(sys.argv[2], dpi=110)
    fig.savefig(sys.argv[3])


if __name__ == "__main__":
    main()
