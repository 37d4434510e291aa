"""The README's picture: a target cloud beside the mesh of the SDF model fitted to it.

    .venv/bin/pip install "./crates/sdfreg-py[docs]"     # matplotlib
    .venv/bin/python docs/model_figure.py --data ../shared/data --output docs/model.png

Uses the bunny's reconstruction bun_zipper.ply (../shared/data/stanford/bunny/reconstruction)
when it is there, else the procedural blob of the tests. Fits `sdfreg.fit` with the defaults and meshes Φ's zero level
set at `--resolution`.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import sdfreg  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=Path("../shared/data"))
    parser.add_argument("--output", type=Path, default=Path("docs/model.png"))
    parser.add_argument("--resolution", type=int, default=96)
    args = parser.parse_args()
    scan = args.data / "stanford" / "bunny" / "reconstruction" / "bun_zipper.ply"
    if scan.is_file():
        cloud, title = sdfreg.read_point_cloud(scan), "bunny (bun_zipper.ply)"
    else:
        rng = np.random.default_rng(0)
        d = rng.standard_normal((4000, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        cloud, title = d * np.array([0.55, 0.4, 0.3]), "procedural blob"
    model = sdfreg.fit(cloud)
    vertices, faces = model.mesh(resolution=args.resolution)
    # Camera: x right, y up (the scans' convention), looking down −z.
    view = dict(elev=10, azim=-80)
    fig = plt.figure(figsize=(10, 5), dpi=110)
    a = fig.add_subplot(1, 2, 1, projection="3d")
    a.scatter(cloud[:, 0], cloud[:, 2], cloud[:, 1], s=0.2, c=cloud[:, 1], cmap="viridis")
    a.set_title(f"{title}: {len(cloud)} points")
    b = fig.add_subplot(1, 2, 2, projection="3d")
    b.plot_trisurf(vertices[:, 0], vertices[:, 2], vertices[:, 1], triangles=faces,
                   color="lightsteelblue", shade=True, linewidth=0, antialiased=True)
    b.set_title(f"Φ = 0 of its model: {len(faces)} triangles")
    lo, hi = cloud.min(0), cloud.max(0)
    for ax in (a, b):
        ax.view_init(**view)
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[2], hi[2])
        ax.set_zlim(lo[1], hi[1])
        ax.set_box_aspect((hi[0] - lo[0], hi[2] - lo[2], hi[1] - lo[1]))
        ax.set_axis_off()
    fig.tight_layout()
    fig.savefig(args.output)
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
