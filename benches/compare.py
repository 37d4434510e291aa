"""sdfreg against the registration tools users would pick instead, on the same pairs.

    benches/compare-env                        # once: a venv with open3d, small_gicp, probreg, the wheel
    .venv-compare/bin/python benches/compare.py --shapes ../shared/data/modelnet40-half1 --pairs 36

Makes the pairs with `sdfreg eval --write-pairs` (the paper's protocols, seeded), runs every method
on every pair, and writes into --out: results.json (every pair, every method), table.md (per
protocol and method: rotation error mean / RMSE / median, translation error mean, the paper's
Euler MAE / RMSE, recall under 5°/0.05, median time) and cdf.png (cumulative rotation-error
curves, one panel per protocol). The paper's own published numbers are added as quoted rows.

Fair parameters, for clouds scaled to a unit bounding box (documented per method below): every
local method starts from the centroid alignment (what sdfreg does itself before its multi-start),
ICP variants get a correspondence distance of 0.5 (half the object: their widest basin without
matching across the whole shape) and up to 100 iterations.

The similarity protocols (`--protocol scaled,scaled-indep`: the source scaled by U[0.5, 2]) run
the methods that estimate a scale: sdfreg with `scale=True`, Open3D's point-to-point ICP with
`with_scaling=True` and probreg's CPD with its scale update, the peers from the centroid
alignment at the ratio of the clouds' RMS radii (the extents' estimate sdfreg starts from too).
Their rows add the scale error in percent (`|ŝ/s − 1|`).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Callable, Dict, List

import numpy as np

import sdfreg
from common import rotation_error_deg

ROOT = Path(__file__).resolve().parents[1]

# The paper's Tables 1–2 (Euler MAE / RMSE of rotation in degrees, MAE / RMSE of translation),
# quoted, per protocol: (MAE(R), RMSE(R), MAE(t), RMSE(t)).
PAPER_ROWS: Dict[str, Dict[str, tuple]] = {
    "ICP (paper)": {
        "clean": (13.887, 23.751, 0.0519, 0.5951),
        "noise": (13.756, 23.459, 0.0511, 0.0585),
        "partial": (23.761, 31.645, 0.1168, 0.1279),
        "density": (14.435, 23.976, 0.0542, 0.0612),
    },
    "PointNetLK (paper)": {
        "clean": (5.2969, 18.123, 0.0039, 0.0241),
        "noise": (13.379, 27.531, 0.0392, 0.0376),
        "partial": (81.365, 79.634, 0.1236, 0.1925),
        "density": (18.693, 30.121, 0.0446, 0.0408),
    },
    "DCP-V2 (paper)": {
        "clean": (2.0072, 3.5501, 0.0037, 0.0050),
        "noise": (5.6346, 12.850, 0.0253, 0.0381),
        "partial": (26.927, 43.275, 0.0981, 0.1168),
        "density": (39.617, 59.627, 0.0091, 0.0318),
    },
    "FMR (paper)": {
        "clean": (4.9820, 14.583, 0.0067, 0.0335),
        "noise": (7.2228, 16.658, 0.0233, 0.0337),
        "partial": (24.813, 30.677, 0.1342, 0.1511),
        "density": (7.5764, 15.830, 0.0201, 0.0208),
    },
    "DeepGMR (paper)": {
        "clean": (9.3220, 18.890, 0.0559, 0.0870),
        "noise": (8.5780, 17.693, 0.0531, 0.0849),
        "partial": (10.227, 19.720, 0.0596, 0.0915),
    },
    "IFR (paper)": {
        "clean": (1.1474, 5.0707, 0.0100, 0.0554),
        "noise": (4.9289, 11.335, 0.0788, 0.1271),
        "partial": (5.0400, 11.728, 0.0232, 0.0233),
        "density": (3.4699, 9.3591, 0.0395, 0.1122),
    },
    "SDFReg (paper)": {
        "clean": (2.5886, 3.1540, 0.0033, 0.0048),
        "noise": (3.9754, 9.1780, 0.0058, 0.0089),
        "partial": (4.1362, 11.596, 0.0056, 0.0103),
        "density": (3.8191, 8.839, 0.0084, 0.0098),
    },
}


# ---------------------------------------------------------------- error measures


def euler_xyz_deg(r: np.ndarray) -> np.ndarray:
    """Angles of r = Rx(a)·Ry(b)·Rz(c), degrees (the protocol's convention)."""
    b = math.asin(max(-1.0, min(1.0, r[0, 2])))
    a = math.atan2(-r[1, 2], r[2, 2])
    c = math.atan2(-r[0, 1], r[0, 0])
    return np.degrees([a, b, c])


def euler_errors(est: np.ndarray, gt: np.ndarray) -> np.ndarray:
    d = euler_xyz_deg(est[:3, :3]) - euler_xyz_deg(gt[:3, :3])
    return (d + 180.0) % 360.0 - 180.0


# ---------------------------------------------------------------- methods


def centroid_init(src: np.ndarray, tgt: np.ndarray) -> np.ndarray:
    init = np.eye(4)
    init[:3, 3] = tgt.mean(0) - src.mean(0)
    return init


def subsample(points: np.ndarray, n: int, seed: int = 0) -> np.ndarray:
    if len(points) <= n:
        return points
    return points[np.random.default_rng(seed).choice(len(points), n, replace=False)]


def method_sdfreg(src, tgt):
    return sdfreg.register(src, tgt, seed=0).transformation


def method_sdfreg_scale(src, tgt):
    return sdfreg.register(src, tgt, seed=0, scale=True).transformation


def similarity_init(src: np.ndarray, tgt: np.ndarray) -> np.ndarray:
    """Centroid alignment at the ratio of the clouds' RMS radii: x = s (p − c_src) + c_tgt."""
    c_src, c_tgt = src.mean(0), tgt.mean(0)
    s = math.sqrt(((tgt - c_tgt) ** 2).sum(1).mean() / ((src - c_src) ** 2).sum(1).mean())
    init = np.eye(4)
    init[:3, :3] *= s
    init[:3, 3] = c_tgt - s * c_src
    return init


def split_similarity(m: np.ndarray) -> tuple:
    """(the rigid part [R | t], s) of a similarity [s R | t]."""
    s = float(np.cbrt(np.linalg.det(m[:3, :3])))
    r = m.copy()
    r[:3, :3] /= s
    return r, s


def scaled_methods() -> Dict[str, Callable]:
    """The methods that estimate a scale, for the similarity protocols."""
    methods: Dict[str, Callable] = {"sdfreg --scale": method_sdfreg_scale}
    try:
        import open3d as o3d

        reg = o3d.pipelines.registration

        def icp_scaled(src, tgt):
            return reg.registration_icp(
                o3d.geometry.PointCloud(o3d.utility.Vector3dVector(src)),
                o3d.geometry.PointCloud(o3d.utility.Vector3dVector(tgt)),
                0.5, similarity_init(src, tgt),
                reg.TransformationEstimationPointToPoint(with_scaling=True),
                reg.ICPConvergenceCriteria(max_iteration=100),
            ).transformation

        methods["Open3D ICP point-to-point, with_scaling"] = icp_scaled
    except ImportError as e:
        print(f"compare.py: skipping Open3D's scaled ICP: {e}", file=sys.stderr)
    try:
        from probreg import cpd

        def cpd_scaled(src, tgt):
            init = similarity_init(src, tgt)
            moved = src @ init[:3, :3].T + init[:3, 3]
            tf, _, _ = cpd.registration_cpd(
                subsample(moved, 1000), subsample(tgt, 1000), tf_type_name="rigid",
                update_scale=True, maxiter=100)
            t = np.eye(4)
            t[:3, :3] = tf.scale * tf.rot
            t[:3, 3] = tf.t
            return t @ init

        methods["probreg CPD, with scale"] = cpd_scaled
    except ImportError as e:
        print(f"compare.py: skipping probreg's CPD: {e}", file=sys.stderr)
    return methods


def open3d_methods() -> Dict[str, Callable]:
    import open3d as o3d

    reg = o3d.pipelines.registration
    icp_distance = 0.5
    criteria = reg.ICPConvergenceCriteria(max_iteration=100)

    def cloud(points, normals=False):
        pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
        if normals:
            # Neighbourhood of 0.05 (5 % of the object), at most 30 points.
            pcd.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=0.05, max_nn=30))
        return pcd

    def icp_p2p(src, tgt):
        return reg.registration_icp(
            cloud(src), cloud(tgt), icp_distance, centroid_init(src, tgt),
            reg.TransformationEstimationPointToPoint(), criteria,
        ).transformation

    def icp_p2l(src, tgt):
        return reg.registration_icp(
            cloud(src), cloud(tgt, True), icp_distance, centroid_init(src, tgt),
            reg.TransformationEstimationPointToPlane(), criteria,
        ).transformation

    def gicp(src, tgt):
        return reg.registration_generalized_icp(
            cloud(src), cloud(tgt), icp_distance, centroid_init(src, tgt),
            reg.TransformationEstimationForGeneralizedICP(), criteria,
        ).transformation

    def fpfh_ransac_icp(src, tgt):
        # Open3D's global-registration recipe at voxel 0.02 (2 % of the object): FPFH at 5
        # voxels, RANSAC inliers at 1.5 voxels, then point-to-plane ICP at 1 voxel... 2 voxels.
        voxel = 0.02
        s, t = cloud(src), cloud(tgt)
        s_down, t_down = s.voxel_down_sample(voxel), t.voxel_down_sample(voxel)
        feats = []
        for pcd in (s_down, t_down):
            pcd.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * voxel, max_nn=30))
            feats.append(reg.compute_fpfh_feature(
                pcd, o3d.geometry.KDTreeSearchParamHybrid(radius=5 * voxel, max_nn=100)))
        o3d.utility.random.seed(0)
        coarse = reg.registration_ransac_based_on_feature_matching(
            s_down, t_down, feats[0], feats[1], True, 1.5 * voxel,
            reg.TransformationEstimationPointToPoint(False), 3,
            [reg.CorrespondenceCheckerBasedOnEdgeLength(0.9),
             reg.CorrespondenceCheckerBasedOnDistance(1.5 * voxel)],
            reg.RANSACConvergenceCriteria(100000, 0.999),
        )
        return reg.registration_icp(
            s, cloud(tgt, True), 2 * voxel, coarse.transformation,
            reg.TransformationEstimationPointToPlane(), criteria,
        ).transformation

    return {
        "Open3D ICP point-to-point": icp_p2p,
        "Open3D ICP point-to-plane": icp_p2l,
        "Open3D GICP": gicp,
        "Open3D FPFH+RANSAC+ICP": fpfh_ransac_icp,
    }


def small_gicp_methods() -> Dict[str, Callable]:
    import small_gicp

    def gicp(src, tgt):
        # Downsampling at 0.01 (keeps nearly every point of a 1024-point cloud),
        # correspondence distance 0.5 as for the ICPs.
        result = small_gicp.align(
            tgt, src, init_T_target_source=centroid_init(src, tgt),
            registration_type="GICP", downsampling_resolution=0.01,
            max_correspondence_distance=0.5, num_threads=2, max_iterations=100,
        )
        return result.T_target_source

    return {"small_gicp GICP": gicp}


def probreg_methods() -> Dict[str, Callable]:
    from probreg import cpd, filterreg

    def as_matrix(tf, src, init):
        t = np.eye(4)
        t[:3, :3] = tf.rot
        t[:3, 3] = tf.t
        return t @ init

    def cpd_rigid(src, tgt):
        # CPD on at most 1000 points per cloud (its cost is quadratic), w = 0 (no outliers).
        init = centroid_init(src, tgt)
        moved = src + init[:3, 3]
        tf, _, _ = cpd.registration_cpd(
            subsample(moved, 1000), subsample(tgt, 1000), tf_type_name="rigid", maxiter=100)
        return as_matrix(tf, src, init)

    def filterreg_rigid(src, tgt):
        init = centroid_init(src, tgt)
        moved = src + init[:3, 3]
        result = filterreg.registration_filterreg(
            subsample(moved, 1000), subsample(tgt, 1000), sigma2=None, maxiter=100)
        return as_matrix(result.transformation, src, init)

    return {"probreg CPD": cpd_rigid, "probreg FilterReg": filterreg_rigid}


# ---------------------------------------------------------------- driver


def make_pairs(args) -> Path:
    pairs = args.out / "pairs"
    cmd = [
        "cargo", "run", "--release", "--quiet", "-p", "sdfreg-cli", "--", "eval",
        "--shapes", str(args.shapes), "--pairs", str(args.pairs), "--protocol", args.protocol,
        "--seed", str(args.seed), "--write-pairs", str(pairs), "--pairs-only", "--force",
    ]
    subprocess.run(cmd, check=True, cwd=ROOT)
    return pairs


def summarise(rows: List[dict]) -> dict:
    rot = [r["rotation_error_deg"] for r in rows]
    tr = [r["translation_error"] for r in rows]
    euler = np.array([r["euler_error_deg"] for r in rows])
    return {
        "pairs": len(rows),
        "rot_mean": statistics.fmean(rot),
        "rot_rmse": math.sqrt(statistics.fmean(x * x for x in rot)),
        "rot_median": statistics.median(rot),
        "t_mean": statistics.fmean(tr),
        "euler_mae": float(np.abs(euler).mean()),
        "euler_rmse": float(np.sqrt((euler ** 2).mean())),
        "recall_5": sum(r["rotation_error_deg"] < 5 and r["translation_error"] < 0.05
                        for r in rows) / len(rows),
        "time_median": statistics.median(r["time_s"] for r in rows),
        **({"scale_error_pct_mean": statistics.fmean(r["scale_error_pct"] for r in rows),
            "scale_error_pct_median": statistics.median(r["scale_error_pct"] for r in rows)}
           if rows and "scale_error_pct" in rows[0] else {}),
    }


def plot(results: List[dict], protocols: List[str], methods: List[str], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cols = min(3, len(protocols))
    rows = math.ceil(len(protocols) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(5 * cols, 3.8 * rows), squeeze=False)
    for ax, protocol in zip(axes.flat, protocols):
        for m in methods:
            errs = np.sort([r["rotation_error_deg"] for r in results
                            if r["protocol"] == protocol and r["method"] == m])
            if len(errs) == 0:
                continue
            frac = np.arange(1, len(errs) + 1) / len(errs)
            style = dict(lw=2.5, color="black") if m == "sdfreg" else dict(lw=1.3)
            ax.step(np.maximum(errs, 1e-3), frac, where="post", label=m, **style)
        ax.set_xscale("log")
        ax.set_xlim(1e-3, 180)
        ax.set_ylim(0, 1.06)
        ax.set_title(protocol)
        ax.set_xlabel("rotation error (°, log; exact results at the left edge)")
        ax.set_ylabel("fraction of pairs ≤ error")
        ax.grid(True, which="both", alpha=0.3)
    for ax in list(axes.flat)[len(protocols):]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def matrix(summary: dict, protocols: List[str], methods: List[str], key: str) -> List[str]:
    """One row per method, one column per protocol: `key` of the summary, the best in bold."""
    lines = ["| method | " + " | ".join(protocols) + " |", "|---|" + "---|" * len(protocols)]
    for m in methods:
        cells = []
        for p in protocols:
            if f"{p}/{m}" not in summary:  # rigid methods skip the similarity protocols
                cells.append("")
                continue
            v = summary[f"{p}/{m}"][key]
            best = min(summary[f"{p}/{mm}"][key] for mm in methods if f"{p}/{mm}" in summary)
            cells.append(f"**{v:.2f}**" if v - best < 5e-4 else f"{v:.2f}")
        lines.append(f"| {m} | " + " | ".join(cells) + " |")
    return lines


def replot(out: Path) -> None:
    """Re-makes cdf.png from out/results.json."""
    data = json.loads((out / "results.json").read_text())
    results = data["results"]
    protocols = list(dict.fromkeys(r["protocol"] for r in results))
    methods = list(dict.fromkeys(r["method"] for r in results))
    plot(results, protocols, methods, out / "cdf.png")
    print(f"written: {out / 'cdf.png'}")


def main() -> None:
    parser = argparse.ArgumentParser(description="sdfreg against peer registration tools")
    parser.add_argument("--shapes", type=Path, help="folder of .ply shapes (required unless --replot)")
    parser.add_argument("--pairs", type=int, default=36)
    parser.add_argument("--protocol", default="paper")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=ROOT / "target" / "compare")
    parser.add_argument("--methods", default="", help="comma-separated substrings to run only some")
    parser.add_argument("--replot", action="store_true", help="only re-make cdf.png from --out")
    args = parser.parse_args()
    if args.replot:
        return replot(args.out)
    if args.shapes is None or not args.shapes.is_dir():
        sys.exit(f"compare.py: {args.shapes}: no such folder of shapes; skipping the comparison")
    args.out.mkdir(parents=True, exist_ok=True)
    pairs_dir = make_pairs(args)
    index = json.loads((pairs_dir / "pairs.json").read_text())

    methods: Dict[str, Callable] = {"sdfreg": method_sdfreg}
    for loader in (open3d_methods, small_gicp_methods, probreg_methods):
        try:
            methods.update(loader())
        except ImportError as e:
            print(f"compare.py: skipping {loader.__name__}: {e}", file=sys.stderr)
    if args.methods:
        wanted = [w.strip() for w in args.methods.split(",")]
        methods = {k: v for k, v in methods.items() if any(w in k for w in wanted)}

    with_scale = scaled_methods() if any(
        p["protocol"].startswith("scaled") for p in index["pairs"]) else {}
    if args.methods:
        with_scale = {k: v for k, v in with_scale.items() if any(w in k for w in wanted)}
    results = []
    for p in index["pairs"]:
        d = pairs_dir / p["dir"]
        src = sdfreg.read_point_cloud(d / "source.ply")
        tgt = sdfreg.read_point_cloud(d / "target.ply")
        gt = np.array(p["t_target_source"])
        scaled = p["protocol"].startswith("scaled")
        if scaled:
            gt, gt_scale = split_similarity(gt)
        run = with_scale if scaled else methods
        for name, fn in run.items():
            start = time.perf_counter()
            try:
                est = np.asarray(fn(src, tgt), dtype=float)
            except Exception as e:  # a peer failing on a pair counts as a failure, not a crash
                print(f"{name} failed on {p['dir']}: {e}", file=sys.stderr)
                est = np.eye(4)
            elapsed = time.perf_counter() - start
            row = {"protocol": p["protocol"], "index": p["index"], "shape": p["shape"],
                   "method": name}
            if scaled:
                est, est_scale = split_similarity(est)
                row["scale_error_pct"] = abs(est_scale / gt_scale - 1.0) * 100.0
            row.update({
                "rotation_error_deg": rotation_error_deg(est, gt),
                "translation_error": float(np.linalg.norm(est[:3, 3] - gt[:3, 3])),
                "euler_error_deg": euler_errors(est, gt).tolist(),
                "time_s": elapsed,
            })
            results.append(row)
        print(f"{p['protocol']} {p['index']:3d} {p['shape']}: " + ", ".join(
            f"{r['method']} {r['rotation_error_deg']:.2f}°" for r in results[-len(run):]),
            flush=True)

    protocols = list(dict.fromkeys(p["protocol"] for p in index["pairs"]))
    lines = [
        f"Pairs: {args.pairs} per protocol from {args.shapes} (seed {args.seed}); "
        f"rotation errors in degrees, translations in units of the shape's largest side.",
        "",
        "| protocol | method | rot mean | rot RMSE | rot median | t mean | Euler MAE(R) "
        "| Euler RMSE(R) | <5°/0.05 | median time (s) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    summary = {}
    for protocol in protocols:
        for m in (with_scale if protocol.startswith("scaled") else methods):
            rows = [r for r in results if r["protocol"] == protocol and r["method"] == m]
            s = summarise(rows)
            summary[f"{protocol}/{m}"] = s
            name = f"**{m}**" if m.startswith("sdfreg") else m
            if "scale_error_pct_mean" in s:
                name += (f" (scale error {s['scale_error_pct_mean']:.3f} % mean, "
                         f"{s['scale_error_pct_median']:.3f} % median)")
            lines.append(
                f"| {protocol} | {name} | {s['rot_mean']:.3f} | {s['rot_rmse']:.3f} | "
                f"{s['rot_median']:.3f} | {s['t_mean']:.4f} | {s['euler_mae']:.3f} | "
                f"{s['euler_rmse']:.3f} | {s['recall_5']:.2f} | {s['time_median']:.3f} |")
        for ref, per in PAPER_ROWS.items():
            if protocol in per:
                mae, rmse, _, _ = per[protocol]
                lines.append(f"| {protocol} | *{ref}, quoted* | | | | | *{mae}* | *{rmse}* | | |")
    lines += ["", "Mean rotation error (°), best in bold:", ""]
    every = [m for m in list(methods) + list(with_scale)
             if any(f"{p}/{m}" in summary for p in protocols)]
    lines += matrix(summary, protocols, every, "rot_mean")
    lines += ["", "Median rotation error (°), best in bold:", ""]
    lines += matrix(summary, protocols, every, "rot_median")
    table = "\n".join(lines) + "\n"
    (args.out / "table.md").write_text(table)
    (args.out / "results.json").write_text(json.dumps(
        {"shapes": str(args.shapes), "pairs": args.pairs, "seed": args.seed,
         "summary": summary, "results": results}, indent=1) + "\n")
    plot(results, protocols, every, args.out / "cdf.png")
    print(table)
    print(f"written: {args.out / 'table.md'}, {args.out / 'results.json'}, {args.out / 'cdf.png'}")


if __name__ == "__main__":
    main()
