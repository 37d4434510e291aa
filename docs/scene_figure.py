"""The README's scene picture: a real LiDAR scan beside the mesh of the SDF model fitted to it.

    benches/compare-env                                   # once: a venv with matplotlib
    .venv-compare/bin/python docs/scene_figure.py --data ../shared/data --output docs/scene.png

Uses the target scan of the outdoor pair (../shared/data/lidar/outdoor_pair/tgt.ply, 84 m
across; skipped with a message without it). Fits `sdfreg.fit` with the
defaults (a local model), meshes Φ's zero level set at `--resolution` cells along the scan's
largest side (a scene's mesh keeps the triangles within a voxel of the scan's points), and
shows both from above at an angle, cropped to `--radius` metres about the sensor.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from mpl_toolkits.mplot3d.art3d import Poly3DCollection  # noqa: E402

import sdfreg  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=Path("../shared/data"))
    parser.add_argument("--output", type=Path, default=Path("docs/scene.png"))
    parser.add_argument("--resolution", type=int, default=512)
    parser.add_argument("--radius", type=float, default=18.0)
    args = parser.parse_args()
    scan = args.data / "lidar" / "outdoor_pair" / "tgt.ply"
    if not scan.is_file():
        raise SystemExit(f"scene_figure.py: {scan} not found; skipped (it needs the real scan)")
    cloud, title = np.asarray(sdfreg.read_point_cloud(scan)), "outdoor LiDAR scan (tgt.ply)"
    cloud = cloud[~np.all(cloud == 0.0, axis=1)]  # missing returns, as sdfreg leaves them out
    model = sdfreg.fit(cloud)
    vertices, faces = model.mesh(resolution=args.resolution)
    d = np.abs(np.asarray(model.distance(cloud)))
    r = args.radius
    near = np.all(np.abs(cloud[:, :2]) < r, axis=1)
    tri = vertices[faces]
    keep = np.all(np.abs(tri[:, :, :2]).max(axis=1) < r, axis=1)
    tri = tri[keep]
    fig = plt.figure(figsize=(12, 5.6), dpi=110)
    a = fig.add_subplot(1, 2, 1, projection="3d")
    c = cloud[near]
    a.scatter(c[:, 0], c[:, 1], c[:, 2], s=0.05, c=c[:, 2], cmap="viridis", vmin=-2.0, vmax=3.0)
    a.set_title(f"{title}: {len(cloud)} points")
    b = fig.add_subplot(1, 2, 2, projection="3d")
    z = tri[:, :, 2].mean(axis=1)
    # Shade by the normal's angle to a light from above-left, tint by height.
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True) + 1e-12
    light = np.array([-0.4, -0.3, 0.87])
    shade = 0.35 + 0.65 * np.abs(n @ light)
    colours = plt.get_cmap("viridis")(np.clip((z + 2.0) / 5.0, 0, 1))
    colours[:, :3] *= shade[:, None]
    b.add_collection3d(Poly3DCollection(tri, facecolors=colours, linewidths=0))
    b.set_title(f"Φ = 0 of its model: {keep.sum()} triangles; median |Φ| on the points "
                f"{100 * np.median(d):.1f} cm")
    for ax in (a, b):
        ax.view_init(elev=40, azim=-60)
        ax.set_xlim(-r, r)
        ax.set_ylim(-r, r)
        ax.set_zlim(-3, 6)
        ax.set_box_aspect((2 * r, 2 * r, 9), zoom=1.9)
        ax.set_axis_off()
    fig.tight_layout()
    fig.savefig(args.output)
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
