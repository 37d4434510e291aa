"""A mesh as its own exact distance field: registering onto it with no fitting."""

from __future__ import annotations

import pickle
from pathlib import Path

import numpy as np
import pytest

import sdfreg
from conftest import pose_errors


def uv_sphere(rings: int = 24) -> tuple[np.ndarray, np.ndarray]:
    """A closed ellipsoid mesh, outward winding (poles and a latitude–longitude grid)."""
    around = 2 * rings
    theta = np.pi * np.arange(1, rings) / rings
    phi = 2 * np.pi * np.arange(around) / around
    t, p = np.meshgrid(theta, phi, indexing="ij")
    ring = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1).reshape(-1, 3)
    vertices = np.vstack([[0, 0, 1], ring, [0, 0, -1]]) * [0.6, 0.4, 0.3]
    south = len(vertices) - 1
    at = lambda i, j: 1 + (i - 1) * around + j % around  # noqa: E731
    faces = []
    for j in range(around):
        faces += [[0, at(1, j), at(1, j + 1)], [south, at(rings - 1, j + 1), at(rings - 1, j)]]
        for i in range(1, rings - 1):
            faces += [[at(i, j), at(i + 1, j), at(i + 1, j + 1)], [at(i, j), at(i + 1, j + 1), at(i, j + 1)]]
    return vertices, np.array(faces)


def test_distances_are_exact_and_signed_and_a_scan_registers_without_fitting() -> None:
    vertices, faces = uv_sphere()
    mesh = sdfreg.mesh_model(vertices, faces)
    assert mesh.is_signed
    d = mesh.distance(np.array([[0.0, 0.0, 0.5], [0.0, 0.0, 0.0], vertices[10]]))
    np.testing.assert_allclose(d, [0.2, -0.3, 0.0], atol=5e-4)  # the facets lie within 0.3
    np.testing.assert_allclose(mesh.closest_points([[0.0, 0.0, 0.5]]), [[0.0, 0.0, 0.3]], atol=1e-5)
    # A bumpy asymmetric part of it: points on the faces, cut to one side, moved.
    rng = np.random.default_rng(1)
    samples = mesh.target_points[rng.choice(len(mesh.target_points), 3000, replace=False)]
    scan = samples[samples[:, 0] + 0.5 * samples[:, 1] > -0.1]
    angle = np.radians(25)
    rot = np.array([[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0], [0, 0, 1]])
    truth = np.eye(4)
    truth[:3, :3], truth[:3, 3] = rot, [0.05, -0.02, 0.03]
    source = (scan - truth[:3, 3]) @ rot  # truth maps source into the mesh's frame
    r = mesh.register(source, init=np.eye(4))
    rot_err, trans_err = pose_errors(r.transformation, truth)
    # An ellipsoid's cut part: the remaining symmetry is broken by the cut; started near.
    assert rot_err < 0.5 and trans_err < 0.005, (rot_err, trans_err)
    np.testing.assert_array_equal(sdfreg.register(source, mesh, init=np.eye(4)).transformation, r.transformation)
    back = pickle.loads(pickle.dumps(mesh))
    np.testing.assert_array_equal(back.register(source, init=np.eye(4)).transformation, r.transformation)
    many = sdfreg.register_many([(source, mesh, np.eye(4))])
    np.testing.assert_array_equal(many[0].transformation, r.transformation)


def test_bad_meshes_raise_value_errors_and_read_mesh_reads_faces(tmp_path: Path) -> None:
    vertices, faces = uv_sphere(6)
    with pytest.raises(ValueError, match="target mesh: triangle 0 refers to vertex 999"):
        sdfreg.mesh_model(vertices, [[0, 1, 999]])
    with pytest.raises(ValueError, match="faces: face 0 has a negative index -1"):
        sdfreg.mesh_model(vertices, [[0, 1, -1]])
    with pytest.raises(ValueError, match="faces: expected an \\(F, 3\\) integer array"):
        sdfreg.mesh_model(vertices, faces.astype(float))
    with pytest.raises(ValueError, match="target mesh: no triangles"):
        sdfreg.mesh_model(vertices, np.zeros((0, 3), int))
    with pytest.raises(ValueError, match="refine: True needs an SdfModel target"):
        sdfreg.register(vertices, sdfreg.mesh_model(vertices, faces), refine=True)
    open_mesh = sdfreg.mesh_model(vertices, faces[:-4])
    assert not open_mesh.is_signed
    path = tmp_path / "sphere.ply"
    header = f"ply\nformat ascii 1.0\nelement vertex {len(vertices)}\nproperty float x\nproperty float y\nproperty float z\n"
    header += f"element face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n"
    body = "".join(f"{x} {y} {z}\n" for x, y, z in vertices) + "".join(f"3 {a} {b} {c}\n" for a, b, c in faces)
    path.write_text(header + body)
    v, f = sdfreg.read_mesh(path)
    np.testing.assert_allclose(v, vertices, atol=1e-6)
    np.testing.assert_array_equal(f, faces)
    with pytest.raises(OSError, match="nope.ply"):
        sdfreg.read_mesh(tmp_path / "nope.ply")
    (tmp_path / "folder.ply").mkdir()
    with pytest.raises(IsADirectoryError, match="folder.ply: a directory, not a file"):
        sdfreg.read_mesh(tmp_path / "folder.ply")
