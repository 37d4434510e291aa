"""Registering against a stored model, frozen or refined, against a full registration.

    scripts/python-env                      # once: the venv with the sdfreg wheel
    .venv/bin/python benches/model_modes.py [--pairs 6] [--noise 0.01]

Pairs as the paper's protocol makes them, on the tests' procedural blob (unit bounding box,
Euler angles U[0°, 45°], translation U[−0.5, 0.5]), with N(0, noise²) added to the target. Per
pair, in one run: `sdfreg.register(source, target)`; `sdfreg.fit(target)`; then
`sdfreg.register(source, model)` with Φ frozen and with `refine=True`. Prints the median time of
each and the mean rotation error of the two registrations against the model.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

import sdfreg
from common import blob, euler_xyz, pose_errors


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", type=int, default=6)
    parser.add_argument("--noise", type=float, default=0.01)
    args = parser.parse_args()
    times: dict[str, list[float]] = {"full register": [], "fit": [], "frozen": [], "refined": []}
    errors: dict[str, list[float]] = {"frozen": [], "refined": []}
    for seed in range(args.pairs):
        rng = np.random.default_rng(seed)
        target = blob(1024, rng)
        target -= (target.max(0) + target.min(0)) / 2
        target /= (target.max(0) - target.min(0)).max()
        truth = np.eye(4)
        truth[:3, :3], truth[:3, 3] = euler_xyz(rng.uniform(0, 45, 3)), rng.uniform(-0.5, 0.5, 3)
        source = (target - truth[:3, 3]) @ truth[:3, :3]
        noisy = target + rng.normal(0, args.noise, target.shape)
        t0 = time.perf_counter()
        sdfreg.register(source, noisy)
        times["full register"].append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        model = sdfreg.fit(noisy)
        times["fit"].append(time.perf_counter() - t0)
        for mode, refine in [("frozen", False), ("refined", True)]:
            r = sdfreg.register(source, model, refine=refine)
            times[mode].append(r.time_s)
            errors[mode].append(pose_errors(r.transformation, truth)[0])
    full = statistics.median(times["full register"])
    for mode, t in times.items():
        line = f"{mode:14s} median {1e3 * statistics.median(t):7.1f} ms ({statistics.median(t) / full:5.1%} of a full register)"
        if mode in errors:
            line += f"  mean rotation error {statistics.fmean(errors[mode]):.3f}°"
        print(line)


if __name__ == "__main__":
    main()
