"""Reading and writing a large LAZ file: the KITTI frames tiled to some ten million points.

    scripts/python-env                      # once: the venv with the sdfreg wheel
    .venv/bin/python benches/laz_io.py --data ../shared/data [--copies 14] [--runs 5]

The six frames of `lidar/kitti00_frames` (about 124,000 points each), each copy moved 200 m
along x, are written once to a LAZ file in a temporary folder (`sdfreg.write_point_cloud`,
LASzip chunks of 50,000 points); then the file is read (`sdfreg.read_point_cloud`) and written
again `--runs` times, and written moved (`sdfreg.write_moved_point_cloud`: the records rewritten
in place, every other field kept) as many times. Prints the points, the file's size and the
median times. Two builds are compared by running this with each wheel in turn. Skips with a
message when --data is missing.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import sdfreg


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=Path("../shared/data"))
    parser.add_argument("--copies", type=int, default=14)
    parser.add_argument("--runs", type=int, default=5)
    args = parser.parse_args()
    frames = sorted((args.data / "lidar" / "kitti00_frames").glob("*.ply"))
    if not frames:
        sys.exit(f"laz_io.py: {args.data}/lidar/kitti00_frames: missing; skipping")
    scans = [sdfreg.read_point_cloud(f) for f in frames]
    points = np.concatenate(
        [s + np.array([200.0 * k, 0.0, 0.0]) for k in range(args.copies) for s in scans]
    )
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "tiled.laz"
        sdfreg.write_point_cloud(path, points)
        size = path.stat().st_size
        reads, writes, moves = [], [], []
        c, s_ = np.cos(0.3), np.sin(0.3)
        motion = np.array([[c, -s_, 0, 12.5], [s_, c, 0, -3.0], [0, 0, 1, 0.5], [0, 0, 0, 1]])
        for _ in range(args.runs):
            start = time.perf_counter()
            back = sdfreg.read_point_cloud(path)
            reads.append(time.perf_counter() - start)
            start = time.perf_counter()
            sdfreg.write_point_cloud(Path(folder) / "again.laz", back)
            writes.append(time.perf_counter() - start)
            start = time.perf_counter()
            report = sdfreg.write_moved_point_cloud(path, Path(folder) / "moved.laz", motion)
            moves.append(time.perf_counter() - start)
        assert report["fields_kept"], report
        moved = sdfreg.read_point_cloud(Path(folder) / "moved.laz")
        moved_worst = float(np.abs(moved - (back @ motion[:3, :3].T + motion[:3, 3])).max())
    worst = float(np.abs(back - points).max())
    print(
        f"{len(points)} points, {size / 1e6:.1f} MB: read {statistics.median(reads):.3f} s, "
        f"write {statistics.median(writes):.3f} s, written moved with its fields "
        f"{statistics.median(moves):.3f} s (medians of {args.runs}); read back within "
        f"{worst:.1e} of the points written, the moved file within {moved_worst:.1e} of the "
        f"points moved"
    )


if __name__ == "__main__":
    main()
