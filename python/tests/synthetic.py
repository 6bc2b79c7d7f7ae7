"""A synthetic two-plane scene with known truth, for the Python tests and the install test.

Run as a script it writes the scene's tracks.csv (docs/tracks.md):
    /usr/bin/python3 python/tests/synthetic.py OUT.csv
Needs only numpy (not the rsfm module).
"""
import math
import sys

import numpy as np

FOCAL = 500.0
W, H = 640, 480


def rot(axis, angle):
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


def box_scene(seed=7, frames=60, noise_px=0.3):
    """Rows (frame, track, x, y) and the true unit normals in the first camera frame."""
    rng = np.random.default_rng(seed)
    # Two faces of a box meeting at a vertical edge 5 units in front of the first camera, each
    # receding at 45 degrees: normals at 90 degrees to each other.
    r2 = math.sqrt(0.5)
    faces = [(np.array([-r2, 0.0, r2]), np.array([r2, 0.0, r2])),   # (direction along the face, normal)
             (np.array([r2, 0.0, r2]), np.array([-r2, 0.0, r2]))]
    n1, n2 = faces[0][1], faces[1][1]
    edge = np.array([0.0, 0.0, 5.0])
    pts = []
    for along, _ in faces:
        for _ in range(40):
            pts.append(edge + along * rng.uniform(0.15, 1.5) + np.array([0.0, 1.0, 0.0]) * rng.uniform(-1.2, 1.2))
    pts = np.array(pts)
    rows = []
    for k in range(frames):
        s = k / (frames - 1)
        R = rot([0.2, 1.0, 0.1], 0.25 * s)  # world -> camera rotation
        C = np.array([1.2 * s, -0.3 * s, 0.4 * s])  # camera centre in the world
        Xc = (pts - C) @ R.T
        x = FOCAL * Xc[:, 0] / Xc[:, 2] + (W - 1) / 2 + rng.normal(0, noise_px, len(pts))
        y = FOCAL * Xc[:, 1] / Xc[:, 2] + (H - 1) / 2 + rng.normal(0, noise_px, len(pts))
        for i in range(len(pts)):
            if 0 <= x[i] < W and 0 <= y[i] < H:
                rows.append((k, i, x[i], y[i]))
    return np.array(rows), (n1, n2)


def write_tracks_csv(rows, path):
    """rows (frame, track, x, y) -> a tracks.csv with this scene's image geometry."""
    with open(path, "w") as f:
        f.write(f"# rsfm-tracks 1\n# image_size {W} {H}\n# principal_point {(W - 1) / 2} {(H - 1) / 2}\n")
        f.write(f"# frames {int(rows[0, 0])} {int(rows[-1, 0])}\n# source synthetic box\nframe,track,x,y\n")
        for r in rows:
            f.write(f"{int(r[0])},{int(r[1])},{r[2]:.17g},{r[3]:.17g}\n")


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: synthetic.py OUT.csv")
    write_tracks_csv(box_scene()[0], sys.argv[1])
