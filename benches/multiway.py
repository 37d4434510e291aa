"""Many views: the Stanford bunny's 10 scans through `sdfreg.align` and through Open3D's multiway
pipeline (its tutorial's recipe), accuracy against the ground truth and time, in one run.

    benches/compare-env                       # once: a venv with open3d and the sdfreg wheel
    .venv-compare/bin/python benches/multiway.py --data ../shared/data [--shuffle] [--foreign]

Open3D, as in its multiway-registration tutorial with the global start its docs pair it with:
per pair, FPFH features (voxel 2 mm, features at 5 voxels) matched by RANSAC (1.5 voxels),
refined by point-to-plane ICP (coarse at 15 voxels, fine at 1.5); pose-graph edges between
consecutive scans as odometry, the others as uncertain loop closures, kept only when the ICP's
fitness is at least 0.3; then `global_optimization` (Levenberg–Marquardt, line processes,
edge prune threshold 0.25, reference node 0). sdfreg: `sdfreg.align(scans)` with its defaults.
Errors are each scan's pose against `gt_scan_to_world.txt`, relative to the first scan.
`--shuffle` runs the scans in a seeded random order (the anchor stays bun000); `--foreign`
replaces bun315 (`--foreign SCAN`: that scan) by a ModelNet chair scaled to the bunny's size
(it must be left out). `--seen-from +z` gives `sdfreg.align` where the Stanford scanner stood in
each scan's frame (far along +z), for its free-space check. `--turned SEED` gives every scan
but the anchor a frame of its own, as a scanner's stations have: turned about a random axis by
a random angle up to 180° and moved 0.3 m (two bunny sizes), seeded; errors are measured in the
scans' own frames, as without it.
Then, with no reference, how well each answer lays every placed scan on the others (the
share of its points within 0.5, 1 and 2 mm of another placed scan's, and their RMS distance,
as `Alignment.evaluate` measures it), beside the same figures of the reference's poses.
Skips with a message when --data is missing.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

import sdfreg
from common import pose_errors, rotation_about
from realscans import read_gt_scans

SCANS = ["bun000", "bun045", "bun090", "bun180", "bun270", "bun315", "chin", "ear_back",
         "top2", "top3"]


def open3d_multiway(scans: list[np.ndarray]) -> list[np.ndarray]:
    import open3d as o3d

    reg = o3d.pipelines.registration
    voxel = 0.002
    clouds, downs, feats = [], [], []
    for s in scans:
        pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(s))
        down = pcd.voxel_down_sample(voxel)
        down.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * voxel, max_nn=30))
        feats.append(reg.compute_fpfh_feature(
            down, o3d.geometry.KDTreeSearchParamHybrid(radius=5 * voxel, max_nn=100)))
        clouds.append(pcd)
        downs.append(down)
    o3d.utility.random.seed(0)

    def pair(i: int, j: int):
        coarse = reg.registration_ransac_based_on_feature_matching(
            downs[i], downs[j], feats[i], feats[j], True, 1.5 * voxel,
            reg.TransformationEstimationPointToPoint(False), 3,
            [reg.CorrespondenceCheckerBasedOnEdgeLength(0.9),
             reg.CorrespondenceCheckerBasedOnDistance(1.5 * voxel)],
            reg.RANSACConvergenceCriteria(100000, 0.999))
        icp = reg.registration_icp(downs[i], downs[j], 15 * voxel, coarse.transformation,
                                   reg.TransformationEstimationPointToPlane())
        icp = reg.registration_icp(downs[i], downs[j], 1.5 * voxel, icp.transformation,
                                   reg.TransformationEstimationPointToPlane())
        info = reg.get_information_matrix_from_point_clouds(
            downs[i], downs[j], 1.5 * voxel, icp.transformation)
        return icp.transformation, info, icp.fitness

    graph = reg.PoseGraph()
    odometry = np.eye(4)
    graph.nodes.append(reg.PoseGraphNode(odometry))
    n = len(scans)
    for i in range(n):
        for j in range(i + 1, n):
            t, info, fitness = pair(i, j)  # maps scan i into scan j
            if j == i + 1:
                odometry = t @ odometry
                graph.nodes.append(reg.PoseGraphNode(np.linalg.inv(odometry)))
                graph.edges.append(reg.PoseGraphEdge(i, j, t, info, uncertain=False))
            elif fitness >= 0.3:
                graph.edges.append(reg.PoseGraphEdge(i, j, t, info, uncertain=True))
    reg.global_optimization(
        graph, reg.GlobalOptimizationLevenbergMarquardt(),
        reg.GlobalOptimizationConvergenceCriteria(),
        reg.GlobalOptimizationOption(max_correspondence_distance=1.5 * voxel,
                                     edge_prune_threshold=0.25, reference_node=0))
    return [np.asarray(node.pose) for node in graph.nodes]


def lies_on_others(scans: list[np.ndarray], poses: list, d: float) -> tuple[float, float, float]:
    """Mean and lowest share of a placed scan's points within `d` of the other placed scans'
    (each moved by its pose), and the mean RMS distance of those: `Alignment.evaluate`'s
    figures, for any poses."""
    placed = [k for k, p in enumerate(poses) if p is not None]
    moved = {k: scans[k] @ poses[k][:3, :3].T + poses[k][:3, 3] for k in placed}
    e = [sdfreg.evaluate_registration(moved[k], np.vstack([moved[j] for j in placed if j != k]), d)
         for k in placed]
    return (float(np.mean([x.fitness for x in e])), min(x.fitness for x in e),
            float(np.mean([x.inlier_rmse for x in e])))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=Path("../shared/data"))
    parser.add_argument("--shuffle", action="store_true")
    parser.add_argument("--foreign", nargs="?", const="bun315", default=None, metavar="SCAN",
                        help="replace SCAN (default bun315) by a ModelNet chair")
    parser.add_argument("--no-open3d", action="store_true", help="sdfreg.align alone")
    parser.add_argument("--seen-from", default=None, metavar="VIEW",
                        help="sdfreg.align's free-space check: the scans were seen from VIEW "
                        "(the Stanford scans: +z)")
    parser.add_argument("--turned", type=int, default=None, metavar="SEED",
                        help="every scan but the anchor turned by up to 180° and moved 0.3 m")
    args = parser.parse_args()
    folder = args.data / "stanford" / "bunny" / "data"
    if not folder.is_dir():
        sys.exit(f"multiway.py: {folder}: missing; skipping")
    gt = read_gt_scans(folder / "gt_scan_to_world.txt")
    names = list(SCANS)
    if args.shuffle:
        rest = names[1:]
        np.random.default_rng(0).shuffle(rest)
        names = [names[0]] + rest
    scans = [sdfreg.read_point_cloud(folder / f"{n}.ply") for n in names]
    if args.foreign:
        chairs = sorted((args.data / "modelnet40-half1" / "chair").glob("*.ply"))
        chair = sdfreg.read_point_cloud(chairs[0])
        if args.foreign not in names:
            sys.exit(f"multiway.py: --foreign {args.foreign}: not one of {', '.join(names)}")
        k = names.index(args.foreign)
        names[k] = "chair (foreign)"
        scans[k] = (chair - chair.mean(0)) * 0.15
    truth = {n: np.linalg.inv(gt[names[0]]) @ gt[n] for n in names if n in gt}
    frames = [np.eye(4) for _ in scans]  # each scan's own frame, from its file's
    if args.turned is not None:
        rng = np.random.default_rng(args.turned)
        for k in range(1, len(scans)):
            axis, away = rng.normal(size=3), rng.normal(size=3)
            frames[k] = rotation_about(axis, rng.uniform(0.0, np.pi))
            frames[k][:3, 3] = 0.3 * away / np.linalg.norm(away)
        scans = [s @ f[:3, :3].T + f[:3, 3] for s, f in zip(scans, frames)]
    runs = {}
    start = time.perf_counter()
    a = sdfreg.align(scans, seen_from=args.seen_from)
    runs["sdfreg.align"] = (a.poses, time.perf_counter() - start)
    print(f"sdfreg.align: {a}, stages {a.stage_times_s}, left out {a.left_out}")
    try:
        if args.no_open3d:
            raise ImportError("--no-open3d")
        start = time.perf_counter()
        poses = open3d_multiway(scans)
        runs["Open3D multiway"] = (poses, time.perf_counter() - start)
    except ImportError as e:
        print(f"multiway.py: skipping Open3D: {e}", file=sys.stderr)
    print("| scan | " + " | ".join(runs) + " |")
    print("|---|" + "---|" * len(runs))
    worst = {m: [0.0, 0.0] for m in runs}
    for k, name in enumerate(names):
        cells = []
        for m, (poses, _) in runs.items():
            if poses[k] is None:
                cells.append("left out")
                continue
            if name not in truth:
                cells.append("placed (foreign!)")
                continue
            # A pose maps the scan as given (turned); the truth maps the file's scan.
            rot, trans = pose_errors(poses[k] @ frames[k], truth[name])
            worst[m] = [max(worst[m][0], rot), max(worst[m][1], trans)]
            cells.append(f"{rot:.3f}° / {trans * 1e3:.3f} mm")
        print(f"| {name} | " + " | ".join(cells) + " |")
    print("| worst | " + " | ".join(f"{w[0]:.3f}° / {w[1] * 1e3:.3f} mm" for w in worst.values()) + " |")
    print("| time | " + " | ".join(f"{t:.1f} s" for _, t in runs.values()) + " |")
    # No reference: each answer's scans on each other, and the reference's (its scans only).
    answers = {m: poses for m, (poses, _) in runs.items()}
    answers["reference"] = [truth[n] @ np.linalg.inv(f) if n in truth else None
                            for n, f in zip(names, frames)]
    print("\nEach placed scan on the others (mean share within d / lowest / mean RMS of those):")
    print("| d | " + " | ".join(answers) + " |")
    print("|---|" + "---|" * len(answers))
    for d in (0.0005, 0.001, 0.002):
        cells = [lies_on_others(scans, poses, d) for poses in answers.values()]
        print(f"| {d * 1e3:.1f} mm | " + " | ".join(
            f"{m:.4f} / {lo:.3f} / {rms * 1e3:.4f} mm" for m, lo, rms in cells) + " |")


if __name__ == "__main__":
    main()
