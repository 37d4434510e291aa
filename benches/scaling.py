"""How a full registration's time and peak memory grow with the cloud sizes.

    scripts/python-env                      # once: the venv with the sdfreg wheel (for PLY writing)
    cargo build --release -p sdfreg-cli
    .venv/bin/python benches/scaling.py --sizes 1000,10000,100000,1000000

For each size N it writes a pair of N-point clouds (source and target: independent samples of one
procedural, asymmetric closed surface about 1 unit across, the source moved by a fixed 25° / 0.2
motion) as binary PLY under --out, runs `sdfreg register SOURCE TARGET --output r.json` in a fresh
process and reports: the registration time (the CLI's `time_ms`, reading excluded), the process's
wall time (reading included), its peak resident memory (getrusage ru_maxrss of the child) and the
pose error. A run on 100 points per cloud gives the process's baseline memory. Results go to
--out/scaling.json and a markdown table on stdout.

The core subsamples (seeded) to at most `max_source_points` (4,096) source points for the LM and
`max_target_points` (100,000) target points for the fit, so beyond those sizes only reading the
files, the centroid/box passes and the subsampling grow with N.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

import sdfreg
from common import rotation_error_deg

ROOT = Path(__file__).resolve().parents[1]


def surface(n: int, rng: np.random.Generator) -> np.ndarray:
    """`n` points on a bumpy, asymmetric closed surface (a star-shaped blob, radius 0.3–0.6)."""
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    x, y, z = d.T
    r = 0.45 + 0.08 * np.sin(3 * x + 1) * np.cos(2 * y) + 0.06 * z * z * z + 0.05 * x * y
    return d * r[:, None] * np.array([1.0, 0.8, 0.6])


def motion() -> np.ndarray:
    axis = np.array([0.3, -0.8, 0.5])
    axis /= np.linalg.norm(axis)
    th = math.radians(25)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    t = np.eye(4)
    t[:3, :3] = np.eye(3) + math.sin(th) * k + (1 - math.cos(th)) * k @ k
    t[:3, 3] = [0.2, -0.1, 0.15]
    return t


def run_one(cli: Path, n: int, out: Path) -> dict:
    rng = np.random.default_rng(n)
    d = out / f"n{n}"
    d.mkdir(parents=True, exist_ok=True)
    m = motion()  # maps target coordinates to source coordinates
    tgt = surface(n, rng)
    src = surface(n, rng) @ m[:3, :3].T + m[:3, 3]
    sdfreg.write_point_cloud(d / "source.ply", src)
    sdfreg.write_point_cloud(d / "target.ply", tgt)
    result = d / "r.json"
    if result.exists():
        result.unlink()
    start = time.perf_counter()
    proc = subprocess.Popen([str(cli), "register", str(d / "source.ply"), str(d / "target.ply"),
                             "--output", str(result)])
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - start
    if status != 0:
        sys.exit(f"scaling.py: sdfreg register failed on N={n} (status {status})")
    r = json.loads(result.read_text())
    est = np.array(r["transformation"])
    gt = np.linalg.inv(m)
    return {
        "points": n,
        "register_s": r["time_ms"] / 1000,
        "process_s": wall,
        "peak_rss_mib": usage.ru_maxrss / 1024,  # Linux: kilobytes
        "rotation_error_deg": rotation_error_deg(est, gt),
        "translation_error": float(np.linalg.norm(est[:3, 3] - gt[:3, 3])),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description="time and peak memory against cloud size")
    parser.add_argument("--sizes", default="1000,10000,100000,1000000")
    parser.add_argument("--cli", type=Path, default=ROOT / "target" / "release" / "sdfreg")
    parser.add_argument("--out", type=Path, default=ROOT / "target" / "scaling")
    args = parser.parse_args()
    if not args.cli.is_file():
        sys.exit(f"scaling.py: {args.cli} not found; run `cargo build --release -p sdfreg-cli`")
    sizes = [int(s) for s in args.sizes.split(",")]
    rows = [run_one(args.cli, n, args.out) for n in [100] + sizes]
    base = rows[0]["peak_rss_mib"]
    print(f"baseline (100 points per cloud): {base:.1f} MiB peak\n")
    print("| points per cloud | register (s) | process incl. reading (s) | peak RSS (MiB) "
          "| rotation error (°) | translation error |")
    print("|---:|---:|---:|---:|---:|---:|")
    for r in rows[1:]:
        print(f"| {r['points']:,} | {r['register_s']:.2f} | {r['process_s']:.2f} "
              f"| {r['peak_rss_mib']:.0f} | {r['rotation_error_deg']:.3f} "
              f"| {r['translation_error']:.4f} |")
    (args.out / "scaling.json").write_text(json.dumps({"baseline": rows[0], "rows": rows[1:]},
                                                      indent=1))


if __name__ == "__main__":
    main()
