#!/usr/bin/env python3
"""Which of `sdfreg eval`'s failures are symmetries of the shape, for one or more binaries.

A registration 90° off on a lamp with four equal arms, or turned about a bottle's axis, has a
large rotation error but lays the shape onto itself: no method can tell such poses apart from
the points. This bench re-registers pairs that `sdfreg eval` wrote, with each binary given, and
scores every result both ways:

- the rotation error (geodesic, degrees) and translation error (normalised units), as `eval`;
- the *symmetric* error (ADD-S, after Hinterstoisser et al. 2012, as in the BOP benchmark):
  the error motion E = T_est · T_true⁻¹, which maps the target frame to itself, applied to the
  whole shape (its normalised `--shapes` file), and the mean distance of each moved point to
  the nearest point of the unmoved shape. It is near 0 when E is a symmetry of the shape,
  whatever its angle.

A pair fails when its rotation error is ≥ 5° or its translation error ≥ 0.05 (eval's recall);
a failure whose symmetric error is below `--tolerance` (default 0.01: 1 % of the shape's
largest side) is a *symmetry*, the others are *wrong*. Per protocol and binary it prints the
mean and median rotation error, the failures, and the mean and median over the pairs that are
not symmetries (their pose is determined by the shape).

    sdfreg eval --shapes DATA/modelnet40-half1 --pairs 36 --protocol all --write-pairs P --pairs-only
    python benches/symmetry.py --pairs P --shapes DATA/modelnet40-half1 \\
        --bin old=/path/to/earlier/sdfreg --bin new=target/release/sdfreg \
        --bin "learned=target/release/sdfreg --preset learned"

Each `--bin LABEL=COMMAND` is a binary and, after it, flags for its `sdfreg register` calls.
Skips with a message when the pairs or shapes are missing. Needs numpy and scipy
(benches/compare-env).
"""
from __future__ import annotations

import argparse
import json
import shlex
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import sdfreg
from scipy.spatial import cKDTree

from common import pose_errors


def normalised(points: np.ndarray) -> np.ndarray:
    """The shape as eval makes it: centred on its bounding box, the box's largest side 1."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    return (points - (lo + hi) / 2) / (hi - lo).max()


def symmetric_error(error: np.ndarray, tree: cKDTree, probes: np.ndarray) -> float:
    """ADD-S of the error motion `error` (4×4, target frame): the mean distance of the shape's
    `probes` points, moved by it, to the nearest point of the shape (its k-d `tree`)."""
    moved = probes @ error[:3, :3].T + error[:3, 3]
    return float(tree.query(moved)[0].mean())


def register(command: list[str], pair_dir: Path, out: Path) -> np.ndarray:
    """`command` (a binary and its flags) on one written pair: its 4×4, source into target."""
    subprocess.run([command[0], "register", str(pair_dir / "source.ply"),
                    str(pair_dir / "target.ply"), "-o", str(out), "--force", *command[1:]],
                   check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return np.array(json.loads(out.read_text())["transformation"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--pairs", type=Path, required=True,
                        help="a folder written by `sdfreg eval --write-pairs`")
    parser.add_argument("--shapes", type=Path, required=True, help="eval's --shapes folder")
    parser.add_argument("--bin", action="append", required=True, metavar="LABEL=COMMAND",
                        help="a binary and its flags for `register`, labelled")
    parser.add_argument("--tolerance", type=float, default=0.01)
    parser.add_argument("--probes", type=int, default=2000)
    parser.add_argument("--json", type=Path, help="write every pair's figures here")
    args = parser.parse_args()
    index = args.pairs / "pairs.json"
    if not index.is_file() or not args.shapes.is_dir():
        sys.exit(f"symmetry.py: {index} or {args.shapes} missing; skipping")
    bins = [(b.split("=", 1)[0], shlex.split(b.split("=", 1)[1])) if "=" in b
            else (b, shlex.split(b)) for b in args.bin]
    pairs = json.loads(index.read_text())["pairs"]
    shapes: dict[str, tuple[cKDTree, np.ndarray]] = {}
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "r.json"
        for k, p in enumerate(pairs):
            if p["shape"] not in shapes:
                pts = normalised(np.asarray(sdfreg.read_point_cloud(args.shapes / p["shape"])))
                pick = np.random.default_rng(0).choice(len(pts), min(args.probes, len(pts)),
                                                       replace=False)
                shapes[p["shape"]] = (cKDTree(pts), pts[pick])
            tree, probes = shapes[p["shape"]]
            truth = np.array(p["t_target_source"])
            row = {"protocol": p["protocol"], "shape": p["shape"], "index": p["index"]}
            for label, command in bins:
                est = register(command, args.pairs / p["dir"], out)
                rotation, translation = pose_errors(est, truth)
                row[label] = {
                    "rotation_error_deg": rotation,
                    "translation_error": translation,
                    "symmetric_error": symmetric_error(est @ np.linalg.inv(truth), tree,
                                                       probes),
                }
            rows.append(row)
            print(f"\r{k + 1} of {len(pairs)} pairs", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    if args.json:
        args.json.write_text(json.dumps({"tolerance": args.tolerance, "pairs": rows}, indent=1))
    report(rows, [label for label, _ in bins], args.tolerance)


def report(rows: list[dict], labels: list[str], tolerance: float) -> None:
    def failed(r: dict) -> bool:
        return r["rotation_error_deg"] >= 5 or r["translation_error"] >= 0.05

    protocols = list(dict.fromkeys(r["protocol"] for r in rows))
    print(f"failures: rotation ≥ 5° or translation ≥ 0.05; a symmetry: a failure whose "
          f"symmetric error (ADD-S) is below {tolerance}")
    print("| protocol | binary | mean ° | median ° | failures | of them symmetries "
          "| mean ° without symmetries | median ° |")
    print("|---|---|---|---|---|---|---|---|")
    for protocol in protocols:
        these = [r for r in rows if r["protocol"] == protocol]
        for label in labels:
            res = [r[label] for r in these]
            errs = [x["rotation_error_deg"] for x in res]
            fails = [x for x in res if failed(x)]
            sym = [x for x in fails if x["symmetric_error"] < tolerance]
            kept = [x["rotation_error_deg"] for x in res
                    if not (failed(x) and x["symmetric_error"] < tolerance)]
            print(f"| {protocol} | {label} | {statistics.fmean(errs):.3f} | "
                  f"{statistics.median(errs):.3f} | {len(fails)} | {len(sym)} | "
                  f"{statistics.fmean(kept):.3f} | {statistics.median(kept):.3f} |")
    print("\nfailures that are not symmetries (rotation °, translation, symmetric error):")
    for r in rows:
        for label in labels:
            x = r[label]
            if failed(x) and x["symmetric_error"] >= tolerance:
                print(f"  {label:8s} {r['protocol']:14s} {r['shape']:32s} "
                      f"{x['rotation_error_deg']:7.2f}° {x['translation_error']:.3f} "
                      f"{x['symmetric_error']:.4f}")


if __name__ == "__main__":
    main()
