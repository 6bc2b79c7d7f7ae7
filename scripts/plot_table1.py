#!/usr/bin/python3
"""Fig. 1 of Alon & Sclaroff ([AS99]): trial-averaged estimates per frame against truth.

Usage: plot_table1.py FIG1_DATA.csv OUT.png OUT.svg
Rows: translation (t_X solid, t_Z*beta dashed), rotation quaternion (q0 solid, q2 dashed),
plane (N_X solid, N_Y dashed), inverse focal length beta. Columns: noise levels.
Colours: plane formulation blue, point formulation orange, truth black dotted.
Run with /usr/bin/python3 (Debian's numpy/matplotlib) and MPLBACKEND=Agg.
"""
import csv
import sys
from collections import defaultdict

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def main():
    if len(sys.argv) != 4:
        sys.exit("usage: plot_table1.py FIG1_DATA.csv OUT.png OUT.svg")
    data = defaultdict(lambda: defaultdict(list))
    with open(sys.argv[1], newline="") as f:
        for row in csv.DictReader(f):
            key = (row["formulation"], float(row["noise_px"]))
            for k, v in row.items():
                if k not in ("formulation", "noise_px"):
                    data[key][k].append(float(v))
    if not data:
        sys.exit("plot_table1.py: no data rows in " + sys.argv[1])
    noises = sorted({n for _, n in data})
    panels = [
        ("translation", [("t_x", "-", "$t_X$"), ("t_zb", "--", r"$t_Z\beta$")]),
        ("rotation", [("q0", "-", "$q_0$"), ("q2", "--", "$q_2$")]),
        ("plane N", [("n_x", "-", "$N_X$"), ("n_y", "--", "$N_Y$")]),
        (r"$\beta$", [("beta", "-", r"$\beta$")]),
    ]
    colours = {"plane": "tab:blue", "point": "tab:orange"}
    fig, axes = plt.subplots(len(panels), len(noises), figsize=(4.2 * len(noises), 11),
                             sharex=True, squeeze=False)
    for c, noise in enumerate(noises):
        for r, (title, series) in enumerate(panels):
            ax = axes[r][c]
            truth_drawn = set()
            for form in ("plane", "point"):
                d = data.get((form, noise))
                if not d:
                    continue
                for key, style, label in series:
                    ax.plot(d["frame"], d[key], style, color=colours[form], lw=1.4,
                            label=f"{form} {label}")
                    if key not in truth_drawn:
                        ax.plot(d["frame"], d["true_" + key], ":", color="black", lw=1.0,
                                label=f"truth {label}")
                        truth_drawn.add(key)
            if r == 0:
                ax.set_title(f"noise {noise:g} px")
            if c == 0:
                ax.set_ylabel(title)
            if r == len(panels) - 1:
                ax.set_xlabel("frame")
            if r == 2:
                # The point formulation's fitted N = n/d explodes when a trial's fitted plane
                # passes near the origin (d ~ 0); keep the axis on the truth and plane curves.
                ax.set_ylim(-1.0, 3.0)
            if r == 3:
                ax.set_ylim(0.4, 1.4)
            ax.grid(alpha=0.3)
            if c == len(noises) - 1:
                ax.legend(fontsize=7, loc="best")
    fig.suptitle("Trial-averaged estimates: plane (Alon-Sclaroff) vs point (A&P) filter, "
                 "same noisy tracks", fontsize=11)
    fig.tight_layout()
    fig.savefig(sys.argv[2], dpi=110)
    fig.savefig(sys.argv[3])


if __name__ == "__main__":
    main()
