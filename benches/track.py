"""Tracking against a stored model: a procedural 200-frame sequence, sdfreg and Open3D ICP.

    scripts/python-env                       # the venv with the sdfreg wheel
    .venv/bin/python benches/track.py [--frames 200] [--json out.json]
    benches/compare-env && .venv-compare/bin/python benches/track.py   # with Open3D

The target is the tests' procedural blob (4096 points, about 1.1 units across); frame k is a
fresh independent 1024-point sample of it with N(0, 0.003²) noise, moved by 2° and 0.01 per
frame (a screw with a slow wobble of its axis). sdfreg fits the target once (`sdfreg.fit`) and
tracks the frames with `model.track` (the `tracking` preset: each frame from the previous pose,
5 LM steps on the frozen Φ, a 2-iteration polish), once with all frames in one call and once
streamed, one call per frame as a robot gets them (timed around the call). Open3D, when importable, runs point-to-plane
ICP against the target cloud warm-started the same way (each frame from the previous pose;
max correspondence distance 0.05, 30 iterations). Prints, per method, the median time per frame,
the mean rotation / translation error, and the mean error over the first and the last 50 frames
(drift).
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import time

import numpy as np

import sdfreg
from common import blob, pose_errors


def motion(k: int) -> np.ndarray:
    axis = np.array([0.3, 1.0, 0.2 * math.sin(k * 0.05)])
    axis /= np.linalg.norm(axis)
    th = math.radians(2.0 * k)
    x = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    m = np.eye(4)
    m[:3, :3] = np.eye(3) + math.sin(th) * x + (1 - math.cos(th)) * x @ x
    m[:3, 3] = [0.01 * k, 0.005 * math.sin(k * 0.1), 0.0]
    return m


def summary(name: str, times: list[float], errs: list[tuple[float, float]]) -> dict:
    rot = [e[0] for e in errs]
    row = {
        "method": name,
        "median_ms": 1e3 * statistics.median(times),
        "rotation_mean_deg": statistics.fmean(rot),
        "translation_mean": statistics.fmean(e[1] for e in errs),
        "first50_deg": statistics.fmean(rot[:50]),
        "last50_deg": statistics.fmean(rot[-50:]),
    }
    print(f"{name:44s} median {row['median_ms']:6.2f} ms/frame  mean {row['rotation_mean_deg']:.3f}° "
          f"{row['translation_mean']:.4f}  first 50 {row['first50_deg']:.3f}°  last 50 {row['last50_deg']:.3f}°",
          flush=True)
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=200)
    parser.add_argument("--json")
    args = parser.parse_args()
    target = blob(4096, np.random.default_rng(5))
    truths = [motion(k) for k in range(args.frames)]
    frames = []
    for k, m in enumerate(truths):
        rng = np.random.default_rng(1000 + k)
        pts = blob(1024, rng)
        # frame = m⁻¹ · shape, so that m maps the frame into the target.
        frames.append((pts - m[:3, 3]) @ m[:3, :3] + rng.normal(0, 0.003, pts.shape))
    start = time.perf_counter()
    model = sdfreg.fit(target)
    print(f"sdfreg.fit: {time.perf_counter() - start:.2f} s (once)")
    results = model.track(frames, init=truths[0])
    rows = [summary("sdfreg model.track, all frames in one call", [r.time_s for r in results],
                    [pose_errors(r.transformation, m) for r, m in zip(results, truths)])]
    # Streamed as a robot gets them: one call per frame, from the previous frame's pose, timed
    # around the whole call (the binding and the per-call setup included).
    pose, times, errs = truths[0], [], []
    for f, m in zip(frames, truths):
        t0 = time.perf_counter()
        (r,) = model.track([f], init=pose)
        times.append(time.perf_counter() - t0)
        pose = r.transformation
        errs.append(pose_errors(pose, m))
    rows.append(summary("sdfreg model.track, one call per frame", times, errs))
    try:
        import open3d as o3d
    except ImportError:
        print("open3d is not installed here: ICP skipped (benches/compare-env makes a venv with it)")
    else:
        tgt = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(target))
        tgt.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(20))
        pose, times, errs = truths[0], [], []
        for f, m in zip(frames, truths):
            src = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(f))
            t0 = time.perf_counter()
            r = o3d.pipelines.registration.registration_icp(
                src, tgt, 0.05, pose,
                o3d.pipelines.registration.TransformationEstimationPointToPlane(),
                o3d.pipelines.registration.ICPConvergenceCriteria(max_iteration=30))
            times.append(time.perf_counter() - t0)
            pose = r.transformation
            errs.append(pose_errors(pose, m))
        rows.append(summary("Open3D ICP point-to-plane", times, errs))
    if args.json:
        with open(args.json, "w") as out:
            json.dump(rows, out, indent=1)


if __name__ == "__main__":
    main()
