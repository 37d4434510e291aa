"""Millimetres against metres: a bunny scan in mm registered onto the reconstruction in m.

    scripts/python-env                      # once: the venv with the sdfreg wheel
    .venv/bin/python benches/scale_units.py --data ../shared/data [--scans bun045,bun000,...]

Each scan (`stanford/bunny/data/NAME.ply`, metres) is multiplied by 1000 (millimetres) and
registered with `scale=True`, from no initial guess and no scale range, onto
`reconstruction/bun_zipper.ply` (metres) three ways: the cloud (`sdfreg.register`), a stored
model of it (`sdfreg.fit` once, then `SdfModel.register`) and the mesh's exact distance field
(`sdfreg.mesh_model`). The truth is `[T[:3, :3] / 1000 | T[:3, 3]]` with T the scan's line of
`gt_scan_to_world.txt`. Prints per scan and path the scale error (percent of 0.001), the
rotation error (°), the translation error (mm) and the time. Skips with a message when --data
is missing.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

import sdfreg
from common import pose_errors
from realscans import read_gt_scans


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=Path("../shared/data"))
    parser.add_argument("--scans", default="bun045")
    args = parser.parse_args()
    bunny = args.data / "stanford" / "bunny"
    if not bunny.is_dir():
        sys.exit(f"scale_units.py: {bunny}: missing; skipping")
    gt = read_gt_scans(bunny / "data" / "gt_scan_to_world.txt")
    reconstruction = bunny / "reconstruction" / "bun_zipper.ply"
    target = sdfreg.read_point_cloud(reconstruction)
    start = time.perf_counter()
    model = sdfreg.fit(target)
    fit_s = time.perf_counter() - start
    mesh = sdfreg.mesh_model(*sdfreg.read_mesh(reconstruction))
    paths = {
        "cloud": lambda src: sdfreg.register(src, target, scale=True),
        "stored model": lambda src: model.register(src, scale=True),
        "exact mesh": lambda src: mesh.register(src, scale=True),
    }
    print(f"model of bun_zipper fitted once in {fit_s:.2f} s (not in the times below)")
    print("| scan (mm) | target (m) | scale error (%) | rotation (°) | translation (mm) | time (s) |")
    print("|---|---|---|---|---|---|")
    for name in args.scans.split(","):
        source = sdfreg.read_point_cloud(bunny / "data" / f"{name}.ply") * 1000.0
        truth = gt[name]
        for path, register in paths.items():
            r = register(source)
            rigid = r.transformation.copy()
            rigid[:3, :3] /= r.scale
            rot, trans = pose_errors(rigid, truth)
            print(f"| {name} | {path} | {abs(r.scale / 1e-3 - 1) * 100:.3f} | {rot:.3f} "
                  f"| {trans * 1000:.3f} | {r.time_s:.2f} |", flush=True)


if __name__ == "__main__":
    main()
