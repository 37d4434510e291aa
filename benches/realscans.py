"""sdfreg on real scans: the Stanford bunny's neighbouring views and the 3DMatch pair.

    scripts/python-env                      # once: the venv with the sdfreg wheel
    .venv/bin/python benches/realscans.py --data ../shared/data [--json out.json] [key=value ...]
    .venv-compare/bin/python benches/realscans.py --only 3dmatch --reference   # what gt.txt is worth
    .venv-compare/bin/python benches/realscans.py --only 3dmatch --densify 16  # at a scan's own density

Pairs (metres, every registration from the clouds as they are — no initial guess):
- bunny: bun045→bun000, bun090→bun045, bun180→bun090, bun270→bun180, bun315→bun270,
  bun000→bun315 (source → target); ground truth inv(T_target)·T_source from
  gt_scan_to_world.txt. Also the first pair with both clouds shifted by (10⁶, 10⁶, 10²) m.
- 3dmatch: redkitchen fragment 6 → 0 (gt.txt), and the paper's 3DMatch protocol: fragment 0
  against its own copy moved by a random rotation of up to 60° (uniform axis, angle U[0, 60°])
  and a translation of up to 1 m (uniform direction, length U[0, 1]), --paper-pairs pairs.
  With --densify K (Open3D: benches/compare-env), also the 3DMatch pair made K times denser
  along its surfaces, as a fragment at its own density is (the files are 2.5 cm voxels).

Prints per pair the rotation error (geodesic, °), translation error (mm for the bunny, m for
3DMatch), fitness, whether the robust kernel produced the result, flagged free motions and time.
Settings: sdfreg's defaults (least squares, redone with the robust kernel when it fits poorly
or leaves much of the source outside the target's coverage), overridden by `key=value`
arguments passed to `sdfreg.register` (`preset=scans`: the robust kernel from the start,
multi-start tie 0.05; `robust=off`, …). Skips with a message when --data is missing.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import time
from pathlib import Path

import numpy as np

import sdfreg
from common import pose_errors, rotation_about


BUNNY_PAIRS = [
    ("bun045", "bun000"),
    ("bun090", "bun045"),
    ("bun180", "bun090"),
    ("bun270", "bun180"),
    ("bun315", "bun270"),
    ("bun000", "bun315"),
]


SCAN_SETTINGS: dict[str, object] = {}


def read_gt_scans(path: Path) -> dict[str, np.ndarray]:
    """gt_scan_to_world.txt: a scan's file name, then its 4×4 (p_world = T p_scan)."""
    out: dict[str, np.ndarray] = {}
    lines = [ln for ln in path.read_text().splitlines() if ln.strip() and not ln.startswith("#")]
    i = 0
    while i < len(lines):
        name = Path(lines[i].strip()).stem
        out[name] = np.array([[float(v) for v in lines[i + k].split()] for k in range(1, 5)])
        i += 5
    return out


def run(name: str, src: np.ndarray, tgt: np.ndarray, truth: np.ndarray, unit: float,
        settings: dict, offset: np.ndarray | None = None) -> dict:
    """Registers and scores; with `offset`, both clouds are shifted by it and the estimate is
    mapped back before scoring (a 0.1° error about an origin 10⁶ m away is a 2 km translation
    there, the same pose error at the clouds)."""
    if offset is None:
        r = sdfreg.register(src, tgt, **settings)
        est = r.transformation
    else:
        r = sdfreg.register(src + offset, tgt + offset, **settings)
        est = r.transformation.copy()
        est[:3, 3] += est[:3, :3] @ offset - offset
    rot, tr = pose_errors(est, truth)
    row = {
        "pair": name,
        "transformation": np.asarray(est).tolist(),
        "rotation_error_deg": rot,
        "translation_error_m": tr,
        "fitness": r.fitness,
        "robust": r.robust,
        "free_motions": [repr(f) for f in r.free_motions],
        "time_s": r.time_s,
    }
    row["stages"] = r.stages
    free = f"  free: {len(r.free_motions)}" if r.free_motions else ""
    print(f"{name:28s} {rot:8.3f}° {tr / unit:9.3f} {'mm' if unit < 1 else 'm '}  "
          f"fitness {r.fitness:.3f}{' robust' if r.robust else '       '}  {r.time_s:.2f} s{free}",
          flush=True)
    return row


def reference_worth(match: Path, row: dict) -> None:
    """Point-to-plane ICP and GICP (Open3D, normals from 30 neighbours within 0.1 m) and
    small_gicp's GICP (when installed) started at the published pose of the 3DMatch pair: how
    far each moves from it, and how far sdfreg's answer (`row`) is from where they stop. A
    reference the data's own best fit moves away from cannot score a method closer than that.
    Also, needing no reference, how much of the source sdfreg's answer and gt.txt each lay on
    the target."""
    try:
        import open3d as o3d
    except ImportError:
        print("  --reference needs Open3D: run with .venv-compare/bin/python (benches/compare-env)")
        return
    reg = o3d.pipelines.registration
    src = o3d.io.read_point_cloud(str(match / "src.ply"))
    tgt = o3d.io.read_point_cloud(str(match / "tgt.ply"))
    for pc in (src, tgt):
        pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=0.1, max_nn=30))
    gt = np.loadtxt(match / "gt.txt")
    ours = np.asarray(row["transformation"])
    # The translation error is taken at the source's origin (the camera); on the points it is
    # what the two poses do to them: the rotation error has a lever arm of the scene's depth.
    pts = np.asarray(src.points)
    on_gt = pts @ gt[:3, :3].T + gt[:3, 3]
    nearest = np.asarray(o3d.geometry.PointCloud(o3d.utility.Vector3dVector(on_gt))
                         .compute_point_cloud_distance(tgt))
    overlap = nearest < 0.05
    apart = np.linalg.norm(on_gt - (pts @ ours[:3, :3].T + ours[:3, 3]), axis=1)
    print(f"  sdfreg's pose and gt.txt place the source's points {apart[overlap].mean():.4f} m apart "
          f"on average over the overlap ({overlap.mean():.0%} within 5 cm of the target under "
          f"gt.txt; median {np.median(apart[overlap]):.4f} m), {apart.min():.4f}–{apart.max():.4f} m "
          f"over all; the source's centroid is {np.linalg.norm(pts.mean(0)):.2f} m from its origin")
    # Needing no reference: the share of the source each pose lays within 1, 2, 5 and 10 cm of
    # the target (sdfreg.evaluate_registration, Open3D's fitness), and those points' RMS.
    clouds = [np.asarray(pc.points) for pc in (src, tgt)]
    for label, t in (("sdfreg's answer", ours), ("gt.txt", gt)):
        scores = [(d, sdfreg.evaluate_registration(*clouds, d, t)) for d in (0.01, 0.02, 0.05, 0.1)]
        print(f"  fitness of {label:<15} " + "  ".join(
            f"{d:.2f} m: {e.fitness:.4f} ({e.inlier_rmse * 1e3:.1f} mm)" for d, e in scores))
    for name, est in (("point-to-plane ICP", reg.TransformationEstimationPointToPlane()),
                      ("GICP", reg.TransformationEstimationForGeneralizedICP())):
        for dist in (0.05, 0.1):
            t = reg.registration_icp(src, tgt, dist, gt, est,
                                     reg.ICPConvergenceCriteria(max_iteration=200)).transformation
            a, b = pose_errors(t, gt), pose_errors(t, ours)
            print(f"  Open3D {name} from gt.txt ({dist} m): {a[0]:.3f}° / {a[1]:.3f} m from it, "
                  f"{b[0]:.3f}° / {b[1]:.3f} m from sdfreg's answer")
    try:
        import small_gicp
    except ImportError:
        return
    points = [np.asarray(pc.points) for pc in (src, tgt)]
    for voxel in (0.01, 0.025, 0.05):
        t = small_gicp.align(points[1], points[0], init_T_target_source=gt, registration_type="GICP",
                             downsampling_resolution=voxel, num_threads=2,
                             max_correspondence_distance=0.1).T_target_source
        a, b = pose_errors(t, gt), pose_errors(t, ours)
        print(f"  small_gicp GICP from gt.txt ({voxel} m voxels, 0.1 m): {a[0]:.3f}° / {a[1]:.3f} m "
              f"from it, {b[0]:.3f}° / {b[1]:.3f} m from sdfreg's answer")


def random_motion(rng: np.random.Generator, max_deg: float, max_t: float) -> np.ndarray:
    axis = rng.normal(size=3)
    t = rotation_about(axis, math.radians(rng.uniform(0, max_deg)))
    d = rng.normal(size=3)
    t[:3, 3] = d / np.linalg.norm(d) * rng.uniform(0, max_t)
    return t


def densify(points: np.ndarray, k: int, seed: int = 0) -> np.ndarray:
    """`points` made `k` times denser along their surfaces: each point replaced by `k` drawn
    uniformly over the 2.5 cm square about it in its tangent plane (normals from the 15 nearest
    points, Open3D), so that the cloud's spacing is about 2.5 cm / √k, as a 3DMatch fragment's
    own (before the 2.5 cm voxels of the data folder) is."""
    import open3d as o3d

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(15))
    n = np.asarray(pc.normals)
    helper = np.where(np.abs(n[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    u = np.cross(n, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(n, u)
    off = np.random.default_rng(seed).uniform(-0.0125, 0.0125, (len(points), k, 2))
    dense = points[:, None, :] + off[..., :1] * u[:, None, :] + off[..., 1:] * v[:, None, :]
    return dense.reshape(-1, 3)


def parse_value(v: str):
    for cast in (int, float):
        try:
            return cast(v)
        except ValueError:
            pass
    return {"True": True, "False": False, "None": None}.get(v, v)


def main() -> None:
    parser = argparse.ArgumentParser(description="sdfreg on the bunny scans and 3DMatch")
    parser.add_argument("--data", type=Path, default=Path(__file__).resolve().parents[2]
                        / "shared" / "data")
    parser.add_argument("--paper-pairs", type=int, default=10)
    parser.add_argument("--only", default="", help="bunny, offset, 3dmatch or paper3dmatch")
    parser.add_argument("--reference", action="store_true",
                        help="with Open3D installed (benches/compare-env): how far ICP and GICP "
                        "move from 3DMatch's published pose, what that reference is worth")
    parser.add_argument("--densify", type=int, default=0, metavar="K",
                        help="also the 3DMatch pair made K times denser along its surfaces "
                        "(Open3D: benches/compare-env)")
    parser.add_argument("--json", type=Path)
    parser.add_argument("settings", nargs="*", help="key=value passed to sdfreg.register")
    args = parser.parse_args()
    settings = dict(SCAN_SETTINGS)
    settings.update({k: parse_value(v) for k, v in (s.split("=", 1) for s in args.settings)})
    bunny = args.data / "stanford" / "bunny" / "data"
    match = args.data / "3dmatch" / "redkitchen_06_to_00_vox2.5cm"
    if not bunny.is_dir() and not match.is_dir():
        sys.exit(f"realscans.py: {args.data}: no stanford/bunny or 3dmatch data; skipping")
    only = set(filter(None, args.only.split(",")))
    rows = []
    if bunny.is_dir() and (not only or "bunny" in only or "offset" in only):
        gt = read_gt_scans(bunny / "gt_scan_to_world.txt")
        scans = {n: sdfreg.read_point_cloud(bunny / f"{n}.ply") for n in gt}
        for s, t in BUNNY_PAIRS:
            truth = np.linalg.inv(gt[t]) @ gt[s]
            if not only or "bunny" in only:
                rows.append(run(f"bunny {s}→{t}", scans[s], scans[t], truth, 1e-3, settings))
            if (s, t) == BUNNY_PAIRS[0] and (not only or "offset" in only):
                rows.append(run(f"bunny {s}→{t} +(1e6,1e6,1e2)", scans[s], scans[t], truth,
                                1e-3, settings, offset=np.array([1e6, 1e6, 1e2])))
        bunny_rows = [r for r in rows if r["pair"].startswith("bunny") and "+" not in r["pair"]]
        if bunny_rows:
            ok = sum(r["rotation_error_deg"] < 1 and r["translation_error_m"] < 2e-3
                     for r in bunny_rows)
            print(f"bunny: {ok}/{len(bunny_rows)} under 1° and 2 mm; median "
                  f"{statistics.median(r['rotation_error_deg'] for r in bunny_rows):.3f}° / "
                  f"{1e3 * statistics.median(r['translation_error_m'] for r in bunny_rows):.3f} mm")
    if match.is_dir():
        src = sdfreg.read_point_cloud(match / "src.ply")
        tgt = sdfreg.read_point_cloud(match / "tgt.ply")
        if not only or "3dmatch" in only:
            rows.append(run("3dmatch redkitchen 06→00", src, tgt, np.loadtxt(match / "gt.txt"),
                            1.0, settings))
            if args.reference:
                reference_worth(match, rows[-1])
            if args.densify > 1:
                k = args.densify
                rows.append(run(f"3dmatch redkitchen 06→00 ×{k}", densify(src, k, 0),
                                densify(tgt, k, 1), np.loadtxt(match / "gt.txt"), 1.0, settings))
                kind = rows[-1]["stages"]["global_rerun"]
                print(f"  {len(src) * k} / {len(tgt) * k} points; the local Φ's re-run with a "
                      f"global one: {kind}")
        if not only or "paper3dmatch" in only:
            rng = np.random.default_rng(0)
            paper = []
            for i in range(args.paper_pairs):
                m = random_motion(rng, 60.0, 1.0)  # maps the target copy to the source
                moved = tgt @ m[:3, :3].T + m[:3, 3]
                paper.append(run(f"3dmatch paper protocol {i}", moved, tgt, np.linalg.inv(m),
                                 1.0, settings))
            rows.extend(paper)
            rot = [r["rotation_error_deg"] for r in paper]
            print(f"paper 3DMatch protocol: rotation RMSE {math.sqrt(statistics.fmean(x * x for x in rot)):.3f}°, "
                  f"median {statistics.median(rot):.3f}° (paper: 15.6° / 3.16°)")
    if args.json:
        args.json.write_text(json.dumps({"settings": settings, "pairs": rows}, indent=1))


if __name__ == "__main__":
    main()
