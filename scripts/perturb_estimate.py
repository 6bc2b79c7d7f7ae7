#!/usr/bin/env python3
"""Make a fake 'estimate' directory from a truth directory, for trying `rsfm evaluate`.

Usage: perturb_estimate.py TRUTH_DIR OUT_DIR [--seed 1] [--pos-noise 0.01] [--rot-noise-deg 0.2]
           [--scale 0.5] [--focal-err 0.04] [--normal-err-deg 2] [--drop 10]

The estimate is the truth in another similarity frame (scale --scale, a 10 deg rotation, a shift),
with Gaussian noise on positions (truth units, before scaling) and orientations, every --drop-th
frame removed, the focal length off by --focal-err (relative), plane normals tilted by
--normal-err-deg, planes listed in reverse order plus one spurious plane.
Note: the Sim(3) change of frame is applied to positions only (orientations and normals keep the
reference camera frame), which is what an estimate differing only in scale and gauge looks like
after `rsfm evaluate` aligns it.
"""
import argparse
import json
import math
import os

import numpy as np


def quat_to_mat(x, y, z, w):
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def mat_to_quat(R):
    w = math.sqrt(max(0.0, 1 + R[0, 0] + R[1, 1] + R[2, 2])) / 2
    x = math.copysign(math.sqrt(max(0.0, 1 + R[0, 0] - R[1, 1] - R[2, 2])) / 2, R[2, 1] - R[1, 2])
    y = math.copysign(math.sqrt(max(0.0, 1 - R[0, 0] + R[1, 1] - R[2, 2])) / 2, R[0, 2] - R[2, 0])
    z = math.copysign(math.sqrt(max(0.0, 1 - R[0, 0] - R[1, 1] + R[2, 2])) / 2, R[1, 0] - R[0, 1])
    q = np.array([x, y, z, w])
    return q / np.linalg.norm(q)


def rodrigues(v):
    th = np.linalg.norm(v)
    if th < 1e-15:
        return np.eye(3)
    k = v / th
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(th) * K + (1 - math.cos(th)) * K @ K


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("truth")
    ap.add_argument("out")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--pos-noise", type=float, default=0.01)
    ap.add_argument("--rot-noise-deg", type=float, default=0.2)
    ap.add_argument("--scale", type=float, default=0.5)
    ap.add_argument("--focal-err", type=float, default=0.04)
    ap.add_argument("--normal-err-deg", type=float, default=2.0)
    ap.add_argument("--drop", type=int, default=10)
    a = ap.parse_args()
    rng = np.random.default_rng(a.seed)
    os.makedirs(a.out, exist_ok=True)
    Rg = rodrigues(np.radians(10) * np.array([0.0, 1.0, 0.0]))
    tg = np.array([0.3, -0.1, 0.2])
    lines = ["# perturbed copy of %s (scripts/perturb_estimate.py)" % a.truth]
    for line in open(os.path.join(a.truth, "trajectory.tum")):
        if line.startswith("#") or not line.strip():
            continue
        t, x, y, z, qx, qy, qz, qw = map(float, line.split())
        if a.drop > 0 and int(t) % a.drop == a.drop - 1:
            continue
        p = np.array([x, y, z]) + rng.normal(0, a.pos_noise, 3)
        p = a.scale * Rg @ p + tg
        R = rodrigues(np.radians(a.rot_noise_deg) * rng.normal(0, 1, 3)) @ quat_to_mat(qx, qy, qz, qw)
        q = mat_to_quat(R)
        lines.append("%d %.17g %.17g %.17g %.17g %.17g %.17g %.17g" % (t, *p, *q))
    open(os.path.join(a.out, "trajectory.tum"), "w").write("\n".join(lines) + "\n")
    s = json.load(open(os.path.join(a.truth, "summary.json")))
    est = {k: s[k] for k in ("format", "version", "frames", "image", "principal_point_px")}
    est["focal_px"] = s["focal_px"] * (1 + a.focal_err)
    planes, dists = [], []
    for n, d in zip(s["planes"], s["plane_distances"]):
        n = np.array(n)
        axis = np.cross(n, rng.normal(0, 1, 3))
        axis /= np.linalg.norm(axis)
        planes.append(list(rodrigues(np.radians(a.normal_err_deg) * axis) @ n))
        dists.append(d * a.scale * (1 + rng.normal(0, 0.03)))
    planes.reverse()
    dists.reverse()
    planes.append(list(np.array([0.0, 0.0, 1.0])))
    dists.append(1.0)
    est["planes"] = planes
    est["plane_distances"] = dists
    est["plane_tracks"] = [100] * len(planes)
    est["plane_reprojection_rms_px"] = [0.5] * len(planes)
    json.dump(est, open(os.path.join(a.out, "summary.json"), "w"), indent=2)


if __name__ == "__main__":
    main()
