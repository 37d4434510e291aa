"""The README's picture of many views: the Stanford bunny's 10 scans, each in its own frame,
aligned by `sdfreg.align` from no guesses, and the mesh of the one model of them all.

    .venv/bin/pip install "./crates/sdfreg-py[docs]"     # matplotlib
    .venv/bin/python docs/views_figure.py --data ../shared/data --output docs/views.png

Skips with a message when the bunny's scans are missing.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import sdfreg  # noqa: E402

SCANS = ["bun000", "bun045", "bun090", "bun180", "bun270", "bun315", "chin", "ear_back",
         "top2", "top3"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=Path("../shared/data"))
    parser.add_argument("--output", type=Path, default=Path("docs/views.png"))
    parser.add_argument("--resolution", type=int, default=160)
    args = parser.parse_args()
    folder = args.data / "stanford" / "bunny" / "data"
    if not folder.is_dir():
        sys.exit(f"views_figure.py: {folder}: missing; skipping")
    scans = [sdfreg.read_point_cloud(folder / f"{name}.ply") for name in SCANS]
    a = sdfreg.align(scans)
    print(a, a.stage_times_s)
    vertices, faces = a.model.mesh(resolution=args.resolution)
    colours = plt.cm.tab10(np.linspace(0, 1, len(scans)))
    fig = plt.figure(figsize=(15, 5), dpi=100)
    raw = fig.add_subplot(1, 3, 1, projection="3d")
    placed = fig.add_subplot(1, 3, 2, projection="3d")
    mesh = fig.add_subplot(1, 3, 3, projection="3d")
    for scan, pose, c in zip(scans, a.poses, colours):
        s = scan[::8]
        raw.scatter(s[:, 0], s[:, 2], s[:, 1], s=0.1, color=c)
        if pose is not None:
            m = s @ pose[:3, :3].T + pose[:3, 3]
            placed.scatter(m[:, 0], m[:, 2], m[:, 1], s=0.1, color=c)
    mesh.plot_trisurf(vertices[:, 0], vertices[:, 2], vertices[:, 1], triangles=faces,
                      color="lightsteelblue", shade=True, linewidth=0, antialiased=True)
    titles = [f"{len(scans)} scans, each in its own frame",
              "sdfreg.align: one frame, from no guesses",
              f"one model of them all: {len(faces)} triangles"]
    for ax, title in zip((raw, placed, mesh), titles):
        ax.text2D(0.5, 0.0, title, transform=ax.transAxes, ha="center", fontsize=12)
    lo, hi = vertices.min(0), vertices.max(0)
    for ax in (raw, placed, mesh):
        ax.view_init(elev=10, azim=-80)
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
