#!/usr/bin/env python3
"""What bounds the rotation error on a noisy target: sdfreg's result beside the polish's own
estimator started at the truth, on pairs that `sdfreg eval` wrote.

The engine's last stage (the polish) measures each moved source point against the plane fitted
through its 5 nearest target points (Geman–McClure weights at 3 robust standard deviations).
On the `noise` protocol the target carries N(0, 0.02²) noise, so those planes are noisy, and
the pose that minimises the polish's cost is not the truth. This bench runs that estimator
(re-written here in numpy: point-to-plane Gauss–Newton, the planes re-fitted each iteration)
from sdfreg's pose and from the true pose, and, as the floor that no correspondence-free method
reaches, the Procrustes fit with the true correspondences (the `noise` protocol's source and
target are the same samples). Per pair and on average, rotation errors in degrees:

    sdfreg eval --shapes DATA/modelnet40-half1 --pairs 36 --protocol noise --write-pairs P --pairs-only
    python benches/noise_floor.py --pairs P [--bin target/release/sdfreg] [--protocol noise]

Skips with a message when the pairs are missing. Needs numpy and scipy (benches/compare-env).
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

import sdfreg
from common import rotation_error_deg
from symmetry import register

NEIGHBOURS = 5  # PolishSettings::neighbours' default
SIGMAS = 3.0  # the kernel's scale in robust standard deviations (solve::kernel::SCALE_SIGMAS)


def exp_se3(xi: np.ndarray) -> np.ndarray:
    """The 4×4 of a twist [ω; v] (rotation first), the translation taken as is (small steps)."""
    w = xi[:3]
    theta = float(np.linalg.norm(w))
    k = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
    a = np.sin(theta) / theta if theta > 1e-12 else 1.0
    b = (1 - np.cos(theta)) / theta**2 if theta > 1e-12 else 0.5
    t = np.eye(4)
    t[:3, :3] = np.eye(3) + a * k + b * k @ k
    t[:3, 3] = xi[3:]
    return t


def polish(source: np.ndarray, target: np.ndarray, start: np.ndarray, iterations: int = 300) -> np.ndarray:
    """Point-to-plane Gauss–Newton of `source` onto planes through `target`'s nearest points,
    from the 4×4 `start` (source into target), to convergence."""
    tree = cKDTree(target)
    pose = start.copy()
    for _ in range(iterations):
        x = source @ pose[:3, :3].T + pose[:3, 3]
        _, idx = tree.query(x, NEIGHBOURS)
        nb = target[idx]
        centroid = nb.mean(axis=1)
        spread = nb - centroid[:, None]
        normal = np.linalg.eigh(np.einsum("nki,nkj->nij", spread, spread))[1][:, :, 0]
        r = np.einsum("ni,ni->n", normal, x - centroid)
        scale = SIGMAS * 1.4826 * float(np.median(np.abs(r))) + 1e-15
        w = np.sqrt((scale**2 / (scale**2 + r**2)) ** 2)
        rows = np.hstack([np.cross(x, normal), normal])
        step = np.linalg.lstsq(rows * w[:, None], -r * w, rcond=None)[0]
        pose = exp_se3(step) @ pose
        if np.linalg.norm(step) < 1e-10:
            break
    return pose


def procrustes(source: np.ndarray, target: np.ndarray) -> np.ndarray:
    """The rotation of the least-squares rigid fit with point i ↔ point i."""
    h = (source - source.mean(0)).T @ (target - target.mean(0))
    u, _, vt = np.linalg.svd(h)
    d = np.diag([1.0, 1.0, float(np.sign(np.linalg.det(vt.T @ u.T)))])
    return vt.T @ d @ u.T


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--pairs", type=Path, required=True,
                        help="a folder written by `sdfreg eval --write-pairs`")
    parser.add_argument("--bin", default="target/release/sdfreg", help="the sdfreg binary")
    parser.add_argument("--protocol", default="noise")
    args = parser.parse_args()
    index = args.pairs / "pairs.json"
    if not index.is_file():
        sys.exit(f"noise_floor.py: {index} missing; skipping")
    pairs = [p for p in json.loads(index.read_text())["pairs"] if p["protocol"] == args.protocol]
    columns = ("sdfreg", "polish from sdfreg's pose", "polish from the truth", "Procrustes, true pairs")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for p in pairs:
            d = args.pairs / p["dir"]
            truth = np.array(p["t_target_source"])
            source = np.asarray(sdfreg.read_point_cloud(d / "source.ply"))
            target = np.asarray(sdfreg.read_point_cloud(d / "target.ply"))
            ours = register([args.bin], d, Path(tmp) / "r.json")
            row = [rotation_error_deg(ours, truth),
                   rotation_error_deg(polish(source, target, ours), truth),
                   rotation_error_deg(polish(source, target, truth), truth),
                   rotation_error_deg(procrustes(source, target), truth[:3, :3])
                   if len(source) == len(target) else float("nan")]
            rows.append(row)
            print(f"{p['shape']:34s} " + " ".join(f"{v:7.3f}" for v in row))
    if not rows:
        sys.exit(f"noise_floor.py: no {args.protocol} pairs in {index}")
    print(f"\n{len(rows)} {args.protocol} pairs, rotation error (°), mean / median:")
    for k, name in enumerate(columns):
        values = [r[k] for r in rows]
        print(f"  {name:28s} {statistics.fmean(values):.3f} / {statistics.median(values):.3f}")


if __name__ == "__main__":
    main()
