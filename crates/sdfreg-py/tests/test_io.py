"""Reading and writing point-cloud files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import sdfreg
from conftest import blob


@pytest.mark.parametrize("name", ["a.ply", "a.pcd", "a.e57", "a.xyz", "a.txt", "a.csv", "a.PTS"])
def test_round_trip_is_exact(tmp_path: Path, name: str) -> None:
    points = blob(300, np.random.default_rng(1)) * 1e3 + np.array([6e5, -4e6, 12.5])
    sdfreg.write_point_cloud(tmp_path / name, points)
    back = sdfreg.read_point_cloud(tmp_path / name)
    assert back.dtype == np.float64 and back.shape == (300, 3)
    np.testing.assert_array_equal(back, points)


def test_las_round_trip_keeps_survey_coordinates_to_its_scale(tmp_path: Path) -> None:
    """LAS stores 32-bit integers: at a scale of 10⁻⁹–10⁻⁸ of the extent (here ~2 km: 10⁻⁵ m)."""
    points = blob(300, np.random.default_rng(1)) * 1e3 + np.array([6e5, -4e6, 12.5])
    sdfreg.write_point_cloud(tmp_path / "a.las", points)
    back = sdfreg.read_point_cloud(tmp_path / "a.las")
    assert back.dtype == np.float64 and back.shape == (300, 3)
    extent = np.ptp(points, axis=0).max()
    assert np.abs(back - points).max() <= 5e-9 * extent
    assert (tmp_path / "a.las").read_bytes()[:4] == b"LASF"
    # LAZ: the same values, compressed; a file cut short is refused by name, not a crash.
    sdfreg.write_point_cloud(tmp_path / "a.laz", points)
    np.testing.assert_array_equal(sdfreg.read_point_cloud(tmp_path / "a.laz"), back)
    laz = (tmp_path / "a.laz").read_bytes()
    assert len(laz) < (tmp_path / "a.las").stat().st_size
    (tmp_path / "cut.laz").write_bytes(laz[: len(laz) // 2])
    with pytest.raises(OSError, match=r"cut\.laz: the LASzip chunk table is said to begin"):
        sdfreg.read_point_cloud(tmp_path / "cut.laz")


def test_a_damaged_or_foreign_e57_file_is_refused_by_name(tmp_path: Path) -> None:
    """Every E57 page carries a checksum: one flipped bit is refused, not read to wrong points."""
    sdfreg.write_point_cloud(tmp_path / "a.e57", blob(300, np.random.default_rng(1)))
    e57 = bytearray((tmp_path / "a.e57").read_bytes())
    assert e57[:8] == b"ASTM-E57"
    e57[100] ^= 1
    (tmp_path / "flipped.e57").write_bytes(e57)
    with pytest.raises(OSError, match=r"flipped\.e57: .*invalid checksum .* for page 0"):
        sdfreg.read_point_cloud(tmp_path / "flipped.e57")
    (tmp_path / "cloud.e57").write_text("1 2 3\n4 5 6\n")
    with pytest.raises(OSError, match=r'cloud\.e57: not an E57 file: it begins with "1 2 3'):
        sdfreg.read_point_cloud(tmp_path / "cloud.e57")


def test_e57_scans_are_read_apart_with_their_pose(tmp_path: Path) -> None:
    points = blob(300, np.random.default_rng(3)) + np.array([10.0, -2.0, 0.5])
    sdfreg.write_point_cloud(tmp_path / "a.e57", points)
    scans = sdfreg.read_e57_scans(tmp_path / "a.e57")
    assert len(scans) == 1
    name, pose, back = scans[0]
    assert name is None and pose.shape == (4, 4) and pose.dtype == np.float64
    np.testing.assert_array_equal(pose, np.eye(4))
    np.testing.assert_array_equal(back, points)
    sdfreg.write_point_cloud(tmp_path / "a.ply", points)
    with pytest.raises(OSError, match=r'a\.ply: not an E57 file: it begins with "ply'):
        sdfreg.read_e57_scans(tmp_path / "a.ply")


def test_e57_scans_written_with_names_and_poses_read_back(tmp_path: Path) -> None:
    rng = np.random.default_rng(4)
    turn = np.eye(4)
    turn[:3, :3] = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
    turn[:3, 3] = [5.0, -2.0, 0.25]
    scans = [("north", np.eye(4), blob(200, rng)), (None, turn, blob(150, rng))]
    sdfreg.write_e57_scans(tmp_path / "c.e57", scans)
    back = sdfreg.read_e57_scans(tmp_path / "c.e57")
    assert [name for name, _, _ in back] == ["north", None]
    for (_, pose, points), (_, p, q) in zip(scans, back):
        np.testing.assert_allclose(p, pose, atol=1e-14)
        np.testing.assert_array_equal(q, points)
    # All of them in the file's frame, as read_point_cloud gives them.
    placed = np.vstack([points @ pose[:3, :3].T + pose[:3, 3] for _, pose, points in scans])
    np.testing.assert_allclose(sdfreg.read_point_cloud(tmp_path / "c.e57"), placed, atol=1e-12)
    squashed = np.diag([1.0, 1.0, 0.5, 1.0])
    with pytest.raises(ValueError, match=r"scans\[1\] pose.*not a rigid transform"):
        sdfreg.write_e57_scans(tmp_path / "d.e57", [scans[0], ("x", squashed, scans[1][2])])
    with pytest.raises(ValueError, match=r"scans\[0\].*\(name, pose, points\) triple"):
        sdfreg.write_e57_scans(tmp_path / "d.e57", [scans[0][2]])
    with pytest.raises(ValueError, match=r"scans: not an iterable"):
        sdfreg.write_e57_scans(tmp_path / "d.e57", 3)  # type: ignore[arg-type]
    assert not (tmp_path / "d.e57").exists()


def test_paths_may_be_str_or_pathlike_and_float32_is_written(tmp_path: Path) -> None:
    points = blob(50, np.random.default_rng(2)).astype(np.float32)
    sdfreg.write_point_cloud(str(tmp_path / "a.ply"), points)
    back = sdfreg.read_point_cloud(tmp_path / "a.ply")
    np.testing.assert_array_equal(back, points.astype(np.float64))


def test_ascii_ply_with_extra_properties_and_elements(tmp_path: Path) -> None:
    text = (
        "ply\nformat ascii 1.0\ncomment made by hand\nelement vertex 3\n"
        "property uchar red\nproperty double x\nproperty float y\nproperty int z\n"
        "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
        "255 0.5 1.25 3\n0 -1 0 0\n7 2 2 -2\n3 0 1 2\n"
    )
    (tmp_path / "a.ply").write_text(text)
    np.testing.assert_array_equal(
        sdfreg.read_point_cloud(tmp_path / "a.ply"),
        [[0.5, 1.25, 3.0], [-1.0, 0.0, 0.0], [2.0, 2.0, -2.0]],
    )


def test_text_with_commas_and_extra_columns(tmp_path: Path) -> None:
    (tmp_path / "a.csv").write_text("1,2,3,9\n4, 5, 6, 9\n")
    np.testing.assert_array_equal(
        sdfreg.read_point_cloud(tmp_path / "a.csv"), [[1, 2, 3], [4, 5, 6]]
    )


def test_pcd_as_pcl_writes_it_with_nan_for_missing_returns(tmp_path: Path) -> None:
    """An organised PCL cloud (2×2, one missing return as NaN), binary float32 x y z plus rgb."""
    header = (
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z rgb\n"
        "SIZE 4 4 4 4\nTYPE F F F U\nCOUNT 1 1 1 1\nWIDTH 2\nHEIGHT 2\n"
        "VIEWPOINT 0 0 0 1 0 0 0\nPOINTS 4\nDATA binary\n"
    )
    rows = np.zeros(4, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("rgb", "<u4")])
    rows["x"], rows["y"], rows["z"] = [1, np.nan, 3, 4], [0.5, 0, 2, 2], [-1, 0, 0, 1]
    (tmp_path / "o.pcd").write_bytes(header.encode() + rows.tobytes())
    with pytest.raises(OSError, match=r"o\.pcd: point 1 has a non-finite coordinate"):
        sdfreg.read_point_cloud(tmp_path / "o.pcd")
    with pytest.warns(UserWarning, match=r"o\.pcd: dropped 1 of 4 points"):
        points = sdfreg.read_point_cloud(tmp_path / "o.pcd", drop_non_finite=True)
    np.testing.assert_array_equal(points, [[1, 0.5, -1], [3, 2, 0], [4, 2, 1]])


def test_ascii_ply_as_open3d_writes_it_with_nan_for_missing_returns(tmp_path: Path) -> None:
    """Open3D's (and PCL's) ascii PLY spells a missing return and an undefined normal `nan`."""
    header = (
        "ply\nformat ascii 1.0\ncomment Created by Open3D\nelement vertex 4\n"
        "property double x\nproperty double y\nproperty double z\n"
        "property double nx\nproperty double ny\nproperty double nz\nend_header\n"
    )
    rows = "1 0.5 -1 0 0 1\nnan nan nan 0 0 1\n3 2 .5 nan nan nan\n4 2 1 -nan inf -inf\n"
    (tmp_path / "o.ply").write_text(header + rows)
    with pytest.raises(OSError, match=r"o\.ply:13: point 1 has a non-finite coordinate"):
        sdfreg.read_point_cloud(tmp_path / "o.ply")
    with pytest.warns(UserWarning, match=r"o\.ply: dropped 1 of 4 points"):
        points = sdfreg.read_point_cloud(tmp_path / "o.ply", drop_non_finite=True)
    np.testing.assert_array_equal(points, [[1, 0.5, -1], [3, 2, 0.5], [4, 2, 1]])


def test_a_registered_scan_is_written_moved_with_its_colours_and_missing_returns(
    tmp_path: Path,
) -> None:
    """An organised PCL cloud (binary float32 x y z and rgb, a NaN missing return) registered
    onto its turned copy and written moved: every row in place, rgb to the bit, NaN kept."""
    rng = np.random.default_rng(3)
    points = blob(400, rng)
    points[7] = np.nan
    rows = np.zeros(400, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("rgb", "<u4")])
    rows["x"], rows["y"], rows["z"] = points.T
    rows["rgb"] = rng.integers(0, 2**24, 400)
    header = (
        "VERSION 0.7\nFIELDS x y z rgb\nSIZE 4 4 4 4\nTYPE F F F U\nCOUNT 1 1 1 1\n"
        "WIDTH 20\nHEIGHT 20\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 400\nDATA binary\n"
    )
    source = tmp_path / "scan.pcd"
    source.write_bytes(header.encode() + rows.tobytes())
    c, s = np.cos(0.3), np.sin(0.3)
    truth = np.array([[c, -s, 0, 0.1], [s, c, 0, -0.05], [0, 0, 1, 0.02], [0, 0, 0, 1]])
    kept = rows[np.isfinite(points).all(axis=1)]
    as_f64 = np.stack([kept["x"], kept["y"], kept["z"]], axis=1).astype(np.float64)
    target = as_f64 @ truth[:3, :3].T + truth[:3, 3]
    result = sdfreg.register(as_f64, target)
    out = tmp_path / "moved.pcd"
    report = sdfreg.write_moved_point_cloud(source, out, result.transformation)
    assert report == {"points": 400, "left_in_place": 1, "fields_kept": True, "reason": None}
    body = out.read_bytes()
    start = body.index(b"DATA binary\n") + len(b"DATA binary\n")
    # The header as it was but for the sensor's pose, moved with the points.
    lines = body[:start].decode().splitlines()
    assert lines[:7] + lines[8:] == header.splitlines()[:7] + header.splitlines()[8:]
    viewpoint = np.array(lines[7].split()[1:], dtype=float)
    np.testing.assert_allclose(viewpoint[:3], result.transformation[:3, 3], atol=1e-12)
    moved = np.frombuffer(body[start:], dtype=rows.dtype)
    np.testing.assert_array_equal(moved["rgb"], rows["rgb"])
    assert np.isnan(moved["x"][7])
    got = np.stack([moved["x"], moved["y"], moved["z"]], axis=1).astype(np.float64)
    want = points.astype(np.float32).astype(np.float64) @ truth[:3, :3].T + truth[:3, 3]
    ok = np.isfinite(points).all(axis=1)
    assert np.abs(got[ok] - want[ok]).max() < 1e-4
    # Another format: the coordinates alone, and why.
    report = sdfreg.write_moved_point_cloud(source, tmp_path / "moved.xyz", result.transformation)
    assert report["fields_kept"] is False and "format is not that of" in report["reason"]
    with pytest.raises(ValueError, match="transformation"):
        sdfreg.write_moved_point_cloud(source, out, np.eye(3))
    with pytest.raises(OSError, match=r"missing\.pcd"):
        sdfreg.write_moved_point_cloud(tmp_path / "missing.pcd", out, np.eye(4))
