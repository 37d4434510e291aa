"""One model of the Stanford bunny's reconstruction, every range scan registered onto it.

    scripts/python-env                      # once: the venv with the sdfreg wheel
    .venv/bin/python benches/bunny_model.py --data ../shared/data [--json out.json]

Fits `sdfreg.fit` once to `reconstruction/bun_zipper.ply` (its 35,947 vertices, metres), then
registers each of the ten scans in `data/` (bun000 … bun315, chin, ear_back, top2, top3) against
the model, Φ frozen, with `preset="scans"` — once from the identity (`init=np.eye(4)`, the scans
as they are: up to 90° and more off) and once with the multi-start (no initial guess). Errors
against `gt_scan_to_world.txt` (the reconstruction is in that world frame). Prints the fit time,
each scan's rotation / translation error and time. Then the same with the mesh itself as the
target: `sdfreg.mesh_model(*sdfreg.read_mesh(bun_zipper.ply))`, its exact distance field, no
fitting (its build time in place of the fit time). Skips with a message when --data is missing.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

import sdfreg
from common import pose_errors

SCANS = ["bun000", "bun045", "bun090", "bun180", "bun270", "bun315", "chin", "ear_back", "top2", "top3"]


def read_gt(path: Path) -> dict[str, np.ndarray]:
    lines = [ln for ln in path.read_text().splitlines() if ln.strip() and not ln.startswith("#")]
    return {
        Path(lines[i].strip()).stem: np.array([[float(v) for v in lines[i + k].split()] for k in range(1, 5)])
        for i in range(0, len(lines), 5)
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=Path(__file__).resolve().parents[2] / "shared" / "data")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    bunny = args.data / "stanford" / "bunny"
    if not (bunny / "reconstruction" / "bun_zipper.ply").is_file():
        sys.exit(f"bunny_model.py: {bunny}: no reconstruction/bun_zipper.ply; skipping")
    gt = read_gt(bunny / "data" / "gt_scan_to_world.txt")
    reconstruction = bunny / "reconstruction" / "bun_zipper.ply"
    start = time.perf_counter()
    model = sdfreg.fit(sdfreg.read_point_cloud(reconstruction))
    fit_s = time.perf_counter() - start
    print(f"model of bun_zipper.ply: {len(model.target_points)} points, fit {fit_s:.2f} s", flush=True)
    start = time.perf_counter()
    mesh = sdfreg.mesh_model(*sdfreg.read_mesh(reconstruction))
    mesh_s = time.perf_counter() - start
    print(f"exact field of bun_zipper.ply: {mesh!r}, built in {mesh_s:.2f} s", flush=True)
    rows = []
    summary = []
    for target_name, target in [("fitted", model), ("mesh", mesh)]:
        for start_name, init in [("identity", np.eye(4)), ("multi-start", None)]:
            ok, times, worst = 0, [], (0.0, 0.0)
            for name in SCANS:
                scan = sdfreg.read_point_cloud(bunny / "data" / f"{name}.ply")
                r = sdfreg.register(scan, target, init=init, preset="scans")
                rot, tr = pose_errors(r.transformation, gt[name])
                ok += rot < 0.5 and tr < 1e-3
                times.append(r.time_s)
                worst = (max(worst[0], rot), max(worst[1], tr))
                rows.append({"target": target_name, "start": start_name, "scan": name,
                             "rotation_error_deg": rot, "translation_error_m": tr, "fitness": r.fitness,
                             "time_s": r.time_s, "start_rotation_deg": pose_errors(np.eye(4), gt[name])[0]})
                print(f"{target_name:6s} {start_name:11s} {name:9s} (starts {rows[-1]['start_rotation_deg']:6.1f}° off) "
                      f"{rot:7.3f}° {tr * 1e3:7.3f} mm  fitness {r.fitness:.3f}  {r.time_s:.2f} s", flush=True)
            summary.append(f"{target_name:6s} {start_name:11s}: {ok}/{len(SCANS)} under 0.5° and 1 mm, worst "
                           f"{worst[0]:.3f}° / {worst[1] * 1e3:.3f} mm, median {np.median(times):.2f} s per scan")
    print(f"target build: fit {fit_s:.2f} s, mesh field {mesh_s:.2f} s")
    print("\n".join(summary))
    if args.json:
        args.json.write_text(json.dumps({"fit_s": fit_s, "mesh_s": mesh_s, "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
