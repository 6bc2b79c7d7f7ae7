#!/usr/bin/env python3
"""Reduce a COLMAP text model to rsfm's truth files: trajectory.tum and summary.json.

Usage (normally run by bench/colmap_reference.sh, with /usr/bin/python3; numpy only):
  colmap_extract.py --model DIR --frames F --out OUTDIR [--seconds FILE] [--command STR]
                    [--version 3.8] [--input STR] [--model-id N] [--models N]

DIR holds COLMAP's cameras.txt, images.txt and points3D.txt (`colmap model_converter
--output_type TXT`). Image names must be frame_NNNNNN.<ext>, NNNNNN the frame number (as
colmap_reference.sh writes them). One camera (single_camera) is expected.

Conventions
- COLMAP's images.txt gives, per image, the world -> camera rotation qvec = (w, x, y, z) (Hamilton)
  and translation tvec: X_cam = R_cw X_world + t_cw; the camera centre is C = -R_cw^T t_cw.
  COLMAP's camera frame is x right, y down, z forward, like rsfm's (docs/conventions.md).
- Reference frame r: frame 0 if registered, else the lowest registered frame (summary
  "colmap.reference_frame"). Everything is expressed in camera r's frame: X_ref = R_r X_world + t_r.
- trajectory.tum, one line per registered frame k, ascending: `k tx ty tz qx qy qz qw` with
  p_k = R_r C_k + t_r (camera centre in the reference frame) and q_k the Hamilton quaternion of
  R_r R_k^T (camera k -> reference), normalized, qw >= 0, shortest round-trip decimals. The
  reference frame's line is the identity. Units are COLMAP's (arbitrary scale: compare after a
  Sim(3) alignment, as `rsfm evaluate` does).
- Intrinsics: SIMPLE_RADIAL params are (f, cx, cy, k); k is OpenCV's k1 with k2 = 0 (COLMAP
  distorts normalized coordinates by the factor 1 + k r^2). COLMAP puts the centre of the
  top-left pixel at (0.5, 0.5), rsfm/OpenCV at (0, 0), so principal_point_px = (cx - 0.5, cy - 0.5).
  ("colmap.camera_params" keeps COLMAP's raw values; "radial_distortion" = [k1, 0], the schema's
  optional OpenCV-convention [k1, k2], null when the model has no k1.) Other models: focal_px is the mean of fx, fy,
  k1 is null unless the model has one.
- mean_reprojection_error_px: COLMAP's own figure (mean over 3-D points of each point's mean
  reprojection error, as `colmap model_analyzer` prints it); the per-observation mean
  (weighted by track length) is given too.

Dominant plane (summary "planes"[0], "colmap_dominant_plane"), from all points3D in the reference
frame, with a threshold derived from the data (no fixed units, since COLMAP's scale is arbitrary):
  1. first fit, threshold-free: least quantile of squares (LQS) - among 3000 random triples
     (seed 1), the plane whose 25th percentile of |distance| is smallest (needs the dominant plane
     to hold >= 25 % of the points); its scale sigma1 = q25(|d|) / 0.3186 (0.3186 = the 62.5th
     percentile of N(0,1), so sigma1 is consistent if every point were an inlier and an
     over-estimate, i.e. conservative, otherwise);
  2. RANSAC (3000 random triples, seed 2), maximising the number of points within 3 sigma1,
     then least squares (SVD) on those inliers;
  3. sigma2 = 1.4826 x MAD (median absolute deviation) of the signed distances of those inliers
     (a robust Gaussian sigma; the 3 sigma1 cut barely truncates it), final threshold
     tau = 3 sigma2 ("colmap.plane_inlier_threshold"); inliers = points within tau of the step-2
     plane, least-squares refit, inliers recomputed and refit once more.
  Reported: unit normal n and distance d with n . X = d, d > 0 (n points from the reference
  camera towards the plane), inlier count, RMS inlier distance, tau, all in COLMAP units.
scene_size: over the final plane inliers, the 5th-95th percentile range of their coordinates
along the plane's principal axes (PCA of the inliers: two in-plane axes and the normal), and the
diagonal of that box, sqrt(sum of squared ranges) - a robust extent of the plane's textured
area, independent of the reference camera's orientation.
"""
import argparse
import json
import math
import os
import re
import sys
import time

import numpy as np

T0 = time.monotonic()


def fail(msg):
    print(f"colmap_extract: error: {msg}", file=sys.stderr)
    sys.exit(1)


def data_lines(path):
    if not os.path.isfile(path):
        fail(f"{path}: missing")
    with open(path) as f:
        for ln, line in enumerate(f, 1):
            line = line.rstrip("\n")
            if line.startswith("#"):
                continue
            yield ln, line


def qvec_to_mat(w, x, y, z):
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def mat_to_quat(R):
    """Hamilton (w, x, y, z) of a rotation matrix, normalized, w >= 0 (Shepperd's method)."""
    t = np.trace(R)
    if t > 0:
        s = 2.0 * math.sqrt(1.0 + t)
        q = np.array([0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s])
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = 2.0 * math.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        q = np.array([(R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s])
    elif R[1, 1] > R[2, 2]:
        s = 2.0 * math.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        q = np.array([(R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s])
    else:
        s = 2.0 * math.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        q = np.array([(R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s])
    q /= np.linalg.norm(q)
    return -q if q[0] < 0 else q


def read_cameras(path):
    cams = {}
    for ln, line in data_lines(path):
        tok = line.split()
        if not tok:
            continue
        if len(tok) < 5:
            fail(f"{path}:{ln}: expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]")
        cams[int(tok[0])] = (tok[1], int(tok[2]), int(tok[3]), [float(v) for v in tok[4:]])
    return cams


def read_images(path):
    """{frame: (R_cw, t_cw, camera_id, n_points2D_with_3D)} from images.txt (2 lines per image)."""
    imgs = {}
    lines = [(ln, l) for ln, l in data_lines(path)]
    # The header is followed by pairs of lines; an image without 2-D points has an empty 2nd line.
    i = 0
    while i < len(lines):
        ln, line = lines[i]
        tok = line.split()
        if not tok:
            i += 1
            continue
        if len(tok) < 10:
            fail(f"{path}:{ln}: expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME")
        name = " ".join(tok[9:])
        m = re.fullmatch(r"frame_(\d+)\.\w+", os.path.basename(name))
        if not m:
            fail(f"{path}:{ln}: image name '{name}' is not frame_NNNNNN.<ext>")
        frame = int(m.group(1))
        qw, qx, qy, qz, tx, ty, tz = (float(v) for v in tok[1:8])
        q = np.array([qw, qx, qy, qz])
        q /= np.linalg.norm(q)
        pts = lines[i + 1][1].split() if i + 1 < len(lines) else []
        n3d = sum(1 for j in range(2, len(pts), 3) if pts[j] != "-1")
        if frame in imgs:
            fail(f"{path}:{ln}: frame {frame} appears twice")
        imgs[frame] = (qvec_to_mat(*q), np.array([tx, ty, tz]), int(tok[8]), n3d)
        i += 2
    return imgs


def read_points(path):
    xyz, err, track = [], [], []
    for ln, line in data_lines(path):
        tok = line.split()
        if not tok:
            continue
        if len(tok) < 8:
            fail(f"{path}:{ln}: expected POINT3D_ID X Y Z R G B ERROR TRACK[]")
        xyz.append([float(v) for v in tok[1:4]])
        err.append(float(tok[7]))
        track.append((len(tok) - 8) // 2)
    return np.array(xyz, float).reshape(-1, 3), np.array(err, float), np.array(track, int)


def plane_from_triples(P, idx):
    """Unit normals and offsets (n . X = d) of the planes through triples of points; rows with
    (nearly) collinear triples get a zero normal."""
    a, b, c = P[idx[:, 0]], P[idx[:, 1]], P[idx[:, 2]]
    n = np.cross(b - a, c - a)
    norm = np.linalg.norm(n, axis=1)
    ok = norm > 1e-12 * np.maximum(1.0, np.linalg.norm(b - a, axis=1) * np.linalg.norm(c - a, axis=1))
    n[ok] /= norm[ok, None]
    n[~ok] = 0.0
    return n, np.einsum("ij,ij->i", n, a), ok


def ls_plane(P):
    """Least-squares plane (total least squares: the centroid and the smallest singular vector)."""
    c = P.mean(axis=0)
    _, _, vt = np.linalg.svd(P - c, full_matrices=False)
    n = vt[2]
    return n, float(n @ c)


def fit_dominant_plane(P):
    N = len(P)
    if N < 10:
        fail(f"only {N} 3-D points: too few for a plane")
    iters, batch = 3000, 250
    # 1. LQS: minimize the 25th percentile of |d|.
    rng = np.random.default_rng(1)
    k25 = max(3, int(math.ceil(0.25 * N)) - 1)
    best_q, best = np.inf, None
    for s in range(0, iters, batch):
        idx = np.array([rng.choice(N, 3, replace=False) for _ in range(batch)])
        n, d, ok = plane_from_triples(P, idx)
        dist = np.abs(P @ n[ok].T - d[ok])  # N x valid
        q = np.partition(dist, k25, axis=0)[k25]
        j = int(np.argmin(q))
        if q[j] < best_q:
            best_q, best = float(q[j]), (n[ok][j], d[ok][j])
    if best is None:
        fail("every sampled point triple is degenerate")
    sigma1 = best_q / 0.31863936396437514  # Phi^-1(0.625)
    t1 = 3.0 * sigma1
    # 2. RANSAC with 3 sigma1: most points.
    rng = np.random.default_rng(2)
    best_cnt, best2 = -1, None
    for s in range(0, iters, batch):
        idx = np.array([rng.choice(N, 3, replace=False) for _ in range(batch)])
        n, d, ok = plane_from_triples(P, idx)
        cnt = (np.abs(P @ n[ok].T - d[ok]) < t1).sum(axis=0)
        j = int(np.argmax(cnt))
        if cnt[j] > best_cnt:
            best_cnt, best2 = int(cnt[j]), (n[ok][j], d[ok][j])
    n, d = best2
    inl = np.abs(P @ n - d) < t1
    n, d = ls_plane(P[inl])
    # 3. Threshold from the inliers' robust spread, then two least-squares passes.
    r = P[inl] @ n - d
    sigma2 = 1.4826 * float(np.median(np.abs(r - np.median(r))))
    tau = 3.0 * sigma2
    for _ in range(2):
        inl = np.abs(P @ n - d) < tau
        if inl.sum() < 3:
            fail("the plane fit lost its inliers")
        n, d = ls_plane(P[inl])
    inl = np.abs(P @ n - d) < tau
    if d < 0:
        n, d = -n, -d
    rms = float(np.sqrt(np.mean((P[inl] @ n - d) ** 2)))
    return dict(n=n, d=d, inliers=inl, rms=rms, tau=tau, sigma_lqs=sigma1, sigma_mad=sigma2,
                ransac_inliers_3sigma1=best_cnt)


def scene_size(Q):
    c = Q.mean(axis=0)
    _, _, vt = np.linalg.svd(Q - c, full_matrices=False)
    coords = (Q - c) @ vt.T
    ranges = np.percentile(coords, 95, axis=0) - np.percentile(coords, 5, axis=0)
    return float(np.sqrt(np.sum(ranges ** 2))), ranges


def num(x):
    """Shortest round-trip decimal of a float (Python's repr)."""
    return repr(float(x))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--model", required=True)
    ap.add_argument("--frames", type=int, required=True, help="number of frames of the input")
    ap.add_argument("--out", required=True)
    ap.add_argument("--seconds", help="file of 'stage seconds' lines")
    ap.add_argument("--command", default="")
    ap.add_argument("--version", default="unknown")
    ap.add_argument("--input", default="")
    ap.add_argument("--model-id", default="0")
    ap.add_argument("--models", type=int, default=1)
    a = ap.parse_args()

    cams = read_cameras(os.path.join(a.model, "cameras.txt"))
    imgs = read_images(os.path.join(a.model, "images.txt"))
    X, perr, tlen = read_points(os.path.join(a.model, "points3D.txt"))
    if len(cams) != 1:
        fail(f"{a.model}: expected one camera (single_camera), found {len(cams)}")
    if len(imgs) < 2:
        fail(f"{a.model}: fewer than 2 registered images")
    cam_id, (model, W, H, params) = next(iter(cams.items()))
    if model in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL", "SIMPLE_RADIAL_FISHEYE", "RADIAL_FISHEYE"):
        f, cx, cy = params[0], params[1], params[2]
        k1 = params[3] if len(params) > 3 else None
    else:  # PINHOLE, OPENCV, FULL_OPENCV, ...: fx, fy, cx, cy, (k1, ...)
        f, cx, cy = 0.5 * (params[0] + params[1]), params[2], params[3]
        k1 = params[4] if len(params) > 4 else None

    frames = sorted(imgs)
    ref = 0 if 0 in imgs else frames[0]
    Rr, tr = imgs[ref][0], imgs[ref][1]
    poses = []
    for k in frames:
        Rk, tk = imgs[k][0], imgs[k][1]
        C = -Rk.T @ tk
        p = Rr @ C + tr
        q = mat_to_quat(Rr @ Rk.T)  # (w, x, y, z)
        poses.append((k, p, q))

    P = X @ Rr.T + tr  # points in the reference camera frame
    pl = fit_dominant_plane(P)
    size, ranges = scene_size(P[pl["inliers"]])

    seconds = {}
    if a.seconds and os.path.isfile(a.seconds):
        for line in open(a.seconds):
            tok = line.split()
            if len(tok) == 2:
                seconds[tok[0]] = float(tok[1])
    seconds["extract"] = round(time.monotonic() - T0, 2)
    seconds["total"] = round(sum(seconds.values()), 2)

    obs = int(tlen.sum())
    summary = {
        "format": "rsfm-summary",
        "version": 1,
        "frames": a.frames,
        "image": {"width": W, "height": H},
        "principal_point_px": [cx - 0.5, cy - 0.5],
        "focal_px": f,
        "planes": [[float(v) for v in pl["n"]]],
        "plane_distances": [float(pl["d"])],
        "plane_names": ["colmap_dominant_plane"],
        "scene_size": size,
        "radial_distortion": None if k1 is None else [k1, 0.0],
        "colmap": {
            "version": a.version,
            "camera_model": model,
            "camera_params": params,
            "k1": k1,
            "pixel_convention": "principal_point_px = COLMAP (cx, cy) - 0.5 (COLMAP: top-left pixel centre at "
                                "(0.5, 0.5); rsfm/OpenCV: (0, 0))",
            "registered_frames": len(frames),
            "unregistered_frames": [k for k in range(a.frames) if k not in imgs],
            "reference_frame": ref,
            "model": a.model_id,
            "models_written_by_mapper": a.models,
            "points": int(len(X)),
            "observations": obs,
            "mean_track_length": obs / len(X) if len(X) else None,
            "mean_reprojection_error_px": float(perr.mean()) if len(X) else None,
            "mean_reprojection_error_per_observation_px": float((perr * tlen).sum() / obs) if obs else None,
            "plane_inliers": int(pl["inliers"].sum()),
            "plane_inlier_rms": pl["rms"],
            "plane_inlier_threshold": pl["tau"],
            "plane_sigma_lqs": pl["sigma_lqs"],
            "plane_sigma_mad": pl["sigma_mad"],
            "plane_fit": "LQS(25%) scale -> RANSAC at 3 sigma_lqs -> LS -> threshold 3 x 1.4826 MAD of the inliers' "
                         "distances -> LS on inliers (bench/colmap_extract.py); n . X = d, d > 0, reference camera frame",
            "scene_size_definition": "diagonal of the 5-95 percentile box of the plane inliers along their principal axes",
            "scene_size_ranges": [float(v) for v in ranges],
            "units": "COLMAP model units (arbitrary scale)",
            "input": a.input,
            "seconds": seconds,
            "command": a.command,
        },
    }

    os.makedirs(a.out, exist_ok=True)
    tum = os.path.join(a.out, "trajectory.tum")
    js = os.path.join(a.out, "summary.json")
    with open(tum + ".tmp", "w") as fo:
        fo.write("# COLMAP %s reference (bench/colmap_reference.sh): t tx ty tz qx qy qz qw; t = frame index; "
                 "p = camera centre in the reference (frame %d) camera frame (x right, y down, z forward); "
                 "q = Hamilton rotation camera -> reference; COLMAP units\n" % (a.version, ref))
        for k, p, q in poses:
            fo.write(" ".join([str(k)] + [num(v) for v in p] + [num(q[1]), num(q[2]), num(q[3]), num(q[0])]) + "\n")
    with open(js + ".tmp", "w") as fo:
        json.dump(summary, fo, indent=2)
        fo.write("\n")
    os.replace(tum + ".tmp", tum)
    os.replace(js + ".tmp", js)

    n = pl["n"]
    print(f"colmap_extract: {len(frames)}/{a.frames} frames registered (reference frame {ref}), {len(X)} points, "
          f"mean reprojection error {summary['colmap']['mean_reprojection_error_px']:.4f} px", file=sys.stderr)
    print(f"colmap_extract: {model} f {f:.3f} px, principal point ({cx - 0.5:.3f}, {cy - 0.5:.3f}) px (OpenCV), "
          f"k1 {k1 if k1 is None else round(k1, 5)}", file=sys.stderr)
    print(f"colmap_extract: plane n ({n[0]:.4f}, {n[1]:.4f}, {n[2]:.4f}) d {pl['d']:.4f}, {int(pl['inliers'].sum())} "
          f"inliers within {pl['tau']:.4g} (rms {pl['rms']:.4g}), scene_size {size:.4f}", file=sys.stderr)


if __name__ == "__main__":
    main()
