#!/usr/bin/python3
"""Plots of `rsfm estimate` / `rsfm run` against frame.

Usage: plot_estimate.py TRAJECTORY.tum PLANES.csv ANGLES.csv MOTION.png MOTION.svg NORMALS.png NORMALS.svg FOCAL.png
       FOCAL.svg PROCESS_NOISE.png PROCESS_NOISE.svg ANGLES.png ANGLES.svg
- motion: camera position (tx, ty, tz, reference-camera frame, scene units) and rotation angle
  from the reference frame (deg);
- normals: each plane's unit normal as azimuth/elevation angles (deg) with its 1-sigma band;
- focal: focal length (px) with its 1-sigma band;
- process_noise: the sd of the motion process noise the prediction used per frame (rotation deg,
  translation % of the starting depth; planes.csv q_omega_sd_deg, q_trans_sd_rel);
- angles: each pair of planes' angle (deg, between the normals' lines) with its 1-sigma band
  (angles.csv), the refined angle dashed with its 95 % interval.
planes.csv's rows with estimate "online" are the filter's frame by frame (curves); a row "refined"
is the final refinement's estimate (a dashed line with its 1-sigma band at the right).
Run with /usr/bin/python3 (Debian's matplotlib) and MPLBACKEND=Agg.
"""
import csv
import math
import sys
from collections import defaultdict

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def read_tum(path):
    rows = []
    with open(path) as f:
        for line in f:
            line = line.strip()
            if not line or line.startswith("#"):
                continue
            rows.append([float(v) for v in line.split()])
    return rows


def fnum(s):
    return float("nan") if s in ("NA", "") else float(s)


def finish(fig, ax, ylabel, title, png, svg, grid_which="major"):
    """Labels a one-panel figure against frame and writes it as PNG and SVG."""
    ax.set_xlabel("frame")
    ax.set_ylabel(ylabel)
    ax.grid(alpha=0.3, which=grid_which)
    ax.set_title(title, fontsize=11)
    fig.tight_layout()
    fig.savefig(png, dpi=110)
    fig.savefig(svg)
    plt.close(fig)


def main():
    if len(sys.argv) != 14:
        sys.exit("usage: plot_estimate.py TRAJECTORY.tum PLANES.csv ANGLES.csv MOTION.png MOTION.svg NORMALS.png "
                 "NORMALS.svg FOCAL.png FOCAL.svg PROCESS_NOISE.png PROCESS_NOISE.svg ANGLES.png ANGLES.svg")
    angles_csv = sys.argv[3]
    del sys.argv[3]  # the outputs keep their positions (argv[3..10]); the angles' figure is argv[11], argv[12]
    traj = read_tum(sys.argv[1])
    if not traj:
        sys.exit("plot_estimate.py: no poses in " + sys.argv[1])
    planes = defaultdict(lambda: defaultdict(list))
    focal = {}
    refined = {}  # plane -> (az, el, sd); -1 -> (focal, sd)
    qnoise = {}  # frame -> (omega sd deg, translation sd relative to depth)
    with open(sys.argv[2], newline="") as f:
        for row in csv.DictReader(f):
            fr = int(row["frame"])
            if row.get("estimate", "online") == "refined":
                refined[-1] = (fnum(row["focal_px"]), fnum(row["focal_sd_px"]))
                p = int(row["plane"])
                if p >= 0:
                    nx, ny, nz = fnum(row["nx"]), fnum(row["ny"]), fnum(row["nz"])
                    refined[p] = (math.degrees(math.atan2(nx, nz)), math.degrees(math.asin(max(-1.0, min(1.0, -ny)))),
                                  fnum(row["normal_sd_deg"]))
                continue
            focal[fr] = (fnum(row["focal_px"]), fnum(row["focal_sd_px"]))
            if "q_omega_sd_deg" in row and row["q_omega_sd_deg"] not in ("NA", ""):
                qnoise[fr] = (fnum(row["q_omega_sd_deg"]), fnum(row["q_trans_sd_rel"]))
            p = int(row["plane"])
            if p < 0:
                continue
            d = planes[p]
            d["frame"].append(fr)
            nx, ny, nz = fnum(row["nx"]), fnum(row["ny"]), fnum(row["nz"])
            d["az"].append(math.degrees(math.atan2(nx, nz)))
            d["el"].append(math.degrees(math.asin(max(-1.0, min(1.0, -ny)))))
            d["sd"].append(fnum(row["normal_sd_deg"]))

    # Motion.
    t = [r[0] for r in traj]
    fig, ax = plt.subplots(2, 1, figsize=(8, 6.5), sharex=True)
    for i, name in enumerate(("tx", "ty", "tz")):
        ax[0].plot(t, [r[1 + i] for r in traj], lw=1.4, label=name)
    ax[0].set_ylabel("camera position (scene units)")
    ax[0].legend(fontsize=8)
    ang = [math.degrees(2.0 * math.acos(min(1.0, abs(r[7])))) for r in traj]
    ax[1].plot(t, ang, color="tab:purple", lw=1.4)
    ax[1].set_ylabel("rotation from reference (deg)")
    ax[1].set_xlabel("frame")
    for a in ax:
        a.grid(alpha=0.3)
    fig.suptitle("Camera motion (reference camera frame)", fontsize=11)
    fig.tight_layout()
    fig.savefig(sys.argv[3], dpi=110)
    fig.savefig(sys.argv[4])
    plt.close(fig)

    # Normals.
    fig, ax = plt.subplots(2, 1, figsize=(8, 6.5), sharex=True)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    # Every plane of the filter and of the refinement (a point model's run has refined planes
    # only: its filter has none).
    for p in sorted(set(planes) | {q for q in refined if q >= 0}):
        c = colours[p % len(colours)]
        d = planes.get(p)
        for r, key in enumerate(("az", "el")):
            if d:
                lo = [v - s for v, s in zip(d[key], d["sd"])]
                hi = [v + s for v, s in zip(d[key], d["sd"])]
                ax[r].plot(d["frame"], d[key], color=c, lw=1.4, label=f"plane {p} (filter)")
                ax[r].fill_between(d["frame"], lo, hi, color=c, alpha=0.2, lw=0)
            if p in refined:
                # NA sd: the refinement did not determine the plane (dotted, no band).
                v, sd = refined[p][r], refined[p][2]
                nd = math.isnan(sd)
                ax[r].axhline(v, color=c, ls=":" if nd else "--", lw=1.0,
                              label=(f"plane {p} refined" + (" (not determined)" if nd else "")) if r == 0 else None)
                if not nd:
                    ax[r].axhspan(v - sd, v + sd, color=c, alpha=0.08, lw=0)
    ax[0].set_ylabel("normal azimuth atan2(nx, nz) (deg)")
    ax[1].set_ylabel("normal elevation asin(-ny) (deg)")
    ax[1].set_xlabel("frame")
    for a in ax:
        a.grid(alpha=0.3)
    if planes or any(q >= 0 for q in refined):
        ax[0].legend(fontsize=8)
    if not planes:
        ax[0].text(0.5, 0.5, "point model: no planes in the filter" + (" (refined planes dashed)" if refined else ""),
                   ha="center", transform=ax[0].transAxes)
    if not planes and any(q >= 0 for q in refined) and focal:
        ax[1].set_xlim(min(focal), max(focal))  # the filter's frames (no curve sets them)
    fig.suptitle("Plane normals (reference camera frame, 1-sigma bands)", fontsize=11)
    fig.tight_layout()
    fig.savefig(sys.argv[5], dpi=110)
    fig.savefig(sys.argv[6])
    plt.close(fig)

    # Focal length.
    fr = sorted(focal)
    fv = [focal[k][0] for k in fr]
    fs = [focal[k][1] for k in fr]
    fig, ax = plt.subplots(figsize=(8, 4))
    ax.plot(fr, fv, color="tab:red", lw=1.4, label="filter")
    ax.fill_between(fr, [v - s for v, s in zip(fv, fs)], [v + s for v, s in zip(fv, fs)], color="tab:red",
                    alpha=0.2, lw=0)
    if -1 in refined:
        v, sd = refined[-1]
        nd = math.isnan(sd)  # NA sd: the refinement did not determine the focal length (dotted, no band)
        ax.axhline(v, color="k", ls=":" if nd else "--", lw=1.0, label="refined (not determined)" if nd else "refined")
        if not nd:
            ax.axhspan(v - sd, v + sd, color="k", alpha=0.08, lw=0)
        ax.legend(fontsize=8)
    finish(fig, ax, "focal length (px)", "Focal length estimate (1-sigma band)", sys.argv[7], sys.argv[8])

    # The prediction's process noise per frame (from the motion the start measured, adapted online to
    # the motion the filter measured; jumps are frames taken again on a model mismatch).
    qr = sorted(qnoise)
    fig, ax = plt.subplots(figsize=(8, 4))
    if qr:
        ax.semilogy(qr, [qnoise[k][0] for k in qr], color="tab:blue", lw=1.4, label="rotation sd (deg per frame)")
        ax.semilogy(qr, [100.0 * qnoise[k][1] for k in qr], color="tab:orange", lw=1.4,
                    label="translation sd (% of depth per frame)")
        ax.legend(fontsize=8)
    else:
        ax.text(0.5, 0.5, "no process noise recorded", transform=ax.transAxes, ha="center")
    finish(fig, ax, "process noise sd per frame", "Motion process noise used by the filter's prediction", sys.argv[9],
           sys.argv[10], grid_which="both")

    # Angles between planes.
    online_a = defaultdict(lambda: defaultdict(list))  # (a, b) -> frame, angle, sd
    refined_a = {}  # (a, b) -> (angle, lo, hi)
    with open(angles_csv, newline="") as f:
        for row in csv.DictReader(f):
            key = (int(row["plane_a"]), int(row["plane_b"]))
            if row["estimate"] == "refined":
                refined_a[key] = (fnum(row["angle_deg"]), fnum(row["lo_deg"]), fnum(row["hi_deg"]))
                continue
            d = online_a[key]
            d["frame"].append(int(row["frame"]))
            d["angle"].append(fnum(row["angle_deg"]))
            d["sd"].append(fnum(row["sd_deg"]))
    fig, ax = plt.subplots(figsize=(8, 4))
    pairs = sorted(set(online_a) | set(refined_a))
    for i, key in enumerate(pairs):
        c = colours[i % len(colours)]
        d = online_a.get(key)
        if d:
            ax.plot(d["frame"], d["angle"], color=c, lw=1.4, label=f"planes {key[0]}, {key[1]} (filter)")
            # The angle between lines lies in [0, 90] deg: the band is cut there.
            ax.fill_between(d["frame"], [max(0.0, v - s) for v, s in zip(d["angle"], d["sd"])],
                            [min(90.0, v + s) for v, s in zip(d["angle"], d["sd"])], color=c, alpha=0.2, lw=0)
        if key in refined_a:
            v, lo, hi = refined_a[key]
            nd = math.isnan(lo)
            ax.axhline(v, color=c, ls=":" if nd else "--", lw=1.0,
                       label=f"planes {key[0]}, {key[1]} refined" + (" (not determined)" if nd else ""))
            if not nd:
                ax.axhspan(lo, hi, color=c, alpha=0.08, lw=0)
    if pairs:
        ax.legend(fontsize=8)
    else:
        ax.text(0.5, 0.5, "fewer than two planes: no angle between planes", transform=ax.transAxes, ha="center")
    if not any(online_a.values()) and focal:
        ax.set_xlim(min(focal), max(focal))
    finish(fig, ax, "angle between planes (deg)", "Angles between planes (filter: 1-sigma band; refined: 95 % interval)",
           sys.argv[11], sys.argv[12])


if __name__ == "__main__":
    main()
