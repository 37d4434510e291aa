"""``sdfreg.align``: partial views of one shape into one frame, a foreign view left out, bad
input refused."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import sdfreg
from conftest import QUICK, blob, euler_xyz, pose_errors


def views(n: int, seed: int):
    """``n`` partial views (85 % of a blob, cut by planes of different directions), each moved
    into a frame of its own; and each view's true pose in the first view's frame."""
    rng = np.random.default_rng(seed)
    shape = blob(6000, rng)
    scans, poses = [], []
    for k in range(n):
        a = 2 * np.pi * k / n
        d = np.array([np.cos(a), np.sin(a), 0.3])
        keep = shape @ d > np.quantile(shape @ d, 0.15)
        part = shape[keep][rng.permutation(int(keep.sum()))[:2000]]
        pose = np.eye(4)
        pose[:3, :3] = euler_xyz(rng.uniform(-30, 30, 3))
        pose[:3, 3] = rng.uniform(-0.5, 0.5, 3)
        # The scan in its own frame: p_scan = pose⁻¹ p_world.
        inv = np.linalg.inv(pose)
        scans.append(part @ inv[:3, :3].T + inv[:3, 3])
        poses.append(pose)
    first = np.linalg.inv(poses[0])
    return scans, [first @ p for p in poses]


def test_partial_views_align_and_a_foreign_view_is_left_out(tmp_path: Path) -> None:
    scans, truth = views(4, 1)
    rng = np.random.default_rng(9)
    box = rng.uniform(-0.4, 0.4, (1500, 3))
    box[np.arange(1500), rng.integers(0, 3, 1500)] = rng.choice([-0.4, 0.4], 1500)
    scans.insert(2, box)
    truth.insert(2, None)
    a = sdfreg.align(scans, **QUICK)
    assert isinstance(a, sdfreg.Alignment)
    assert [k for k, _ in a.left_out] == [2]
    assert a.poses[2] is None
    for k, (pose, t) in enumerate(zip(a.poses, truth)):
        if t is None:
            continue
        rot, trans = pose_errors(pose, t)
        assert rot < 1.0 and trans < 0.01, (k, rot, trans)
    kept = [e for e in a.edges if e["kept"]]
    assert kept and all(isinstance(e["registration"], sdfreg.Registration) for e in kept)
    assert all(2 not in (e["source"], e["target"]) for e in kept)
    assert set(a.stage_times_s) == {"models", "pairs", "graph", "unplaced", "consensus", "joint"}
    assert a.consensus["iterations"] == 0 and a.stage_times_s["consensus"] < 0.01
    # Each placed view against the others, no reference: the same figures as
    # evaluate_registration of the view against the others moved by their poses; the box None.
    evaluations = a.evaluate(scans, 0.02)
    assert evaluations[2] is None
    for k in (0, 1, 3, 4):
        others = np.vstack([scans[j] @ a.poses[j][:3, :3].T + a.poses[j][:3, 3] for j in (0, 1, 3, 4) if j != k])
        e = sdfreg.evaluate_registration(scans[k], others, 0.02, a.poses[k])
        got = evaluations[k]
        assert (got.fitness, got.inliers, got.source_points) == (e.fitness, e.inliers, e.source_points)
        assert abs(got.inlier_rmse - e.inlier_rmse) < 1e-9 and got.fitness > 0.8
    # A view moved 0.05 off its pose lies on the others far less.
    assert evaluations[1].fitness - 0.3 > sdfreg.evaluate_registration(
        scans[1] + [0.05, 0, 0], np.vstack([scans[j] @ a.poses[j][:3, :3].T + a.poses[j][:3, 3] for j in (0, 3, 4)]), 0.02, a.poses[1]).fitness
    with pytest.raises(ValueError, match="scans: 4 scans for an alignment of 5"):
        a.evaluate(scans[:4], 0.02)
    with pytest.raises(ValueError, match="max_distance: must be a positive finite number"):
        a.evaluate(scans, 0.0)
    # One model of them all: every placed view lies on it.
    moved = scans[1] @ a.poses[1][:3, :3].T + a.poses[1][:3, 3]
    assert np.median(np.abs(a.model.distance(moved))) < 0.01
    # The poses file: written as the CLI writes it, read back to the last digits, a left-out
    # scan as None; the placed views' poses start another alignment that keeps them.
    names = [f"view_{k}.ply" for k in range(len(scans))]
    text = a.to_json(names)
    assert '"format": "sdfreg-poses"' in text and '"view_2.ply"' in text
    path = tmp_path / "poses.json"
    path.write_text(text, encoding="utf-8")
    back = sdfreg.read_poses(path)
    assert back[2] is None and len(back) == len(scans)
    for k, pose in enumerate(a.poses):
        if pose is not None:
            assert np.abs(back[k] - pose).max() < 1e-12, k
    placed = [k for k in range(len(scans)) if k != 2]
    again = sdfreg.align([scans[k] for k in placed], init=[back[k] for k in placed], **QUICK)
    for k, pose in zip(placed, again.poses):
        rot, trans = pose_errors(pose, truth[k])
        assert rot < 1.0 and trans < 0.01, (k, rot, trans)
    assert '"file": "scan 0"' in again.to_json()
    # A scan without a pose in init (as read_poses gives one left out) starts from nothing.
    gap = sdfreg.align([scans[k] for k in placed], init=[back[0], None, back[3], back[4]], **QUICK)
    for k, pose in zip(placed, gap.poses):
        rot, trans = pose_errors(pose, truth[k])
        assert rot < 1.0 and trans < 0.01, (k, rot, trans)
    given = {(e["source"], e["target"]): e["registration"].stages["initial"]["given"] for e in gap.edges}
    assert all(g == (1 not in pair) for pair, g in given.items()), given
    with pytest.raises(ValueError, match="files: 1 names for 5 scans"):
        a.to_json(["one.ply"])
    # Files that are not poses files: refused as OSError, naming the file and what is wrong.
    with pytest.raises(FileNotFoundError, match="missing.json"):
        sdfreg.read_poses(tmp_path / "missing.json")
    for name, content, what in [
        ("cut.json", text[: len(text) // 2], "not a poses file"),
        ("cloud.json", "1 2 3\n", "not a poses file"),
        ("batch.json", '{"format": "sdfreg-batch-results", "version": 1}', "not a poses file"),
        ("newer.json", text.replace('"version": 1', '"version": 9'), "newer"),
        ("skewed.json", text.replace("[\n        [\n          1.0", "[\n        [\n          2.0", 1), "scans\\[0\\]"),
    ]:
        (tmp_path / name).write_text(content, encoding="utf-8")
        with pytest.raises(OSError, match=f"{name}.*{what}"):
            sdfreg.read_poses(tmp_path / name)


def test_the_anchor_and_bad_input() -> None:
    scans, truth = views(3, 2)
    a = sdfreg.align(scans, anchor=1, **QUICK)
    assert a.anchor == 1
    rot, trans = pose_errors(a.poses[0], np.linalg.inv(truth[1]) @ truth[0])
    assert rot < 1.0 and trans < 0.01
    # The multi-view refinement keeps the poses within the same bounds and lowers the residual.
    c = sdfreg.align(scans, anchor=1, consensus_iterations=30, **QUICK)
    assert c.consensus["pairs"] >= 4 and 1 <= c.consensus["iterations"] <= 30
    assert c.consensus["mean_residual_after"] <= c.consensus["mean_residual_before"]
    for k in (0, 2):
        rot, trans = pose_errors(c.poses[k], np.linalg.inv(truth[1]) @ truth[k])
        assert rot < 1.0 and trans < 0.01, (k, rot, trans)
    with pytest.raises(ValueError, match="consensus_iterations"):
        sdfreg.align(scans, consensus_iterations=-1)
    with pytest.raises(ValueError, match="closure_pairs"):
        sdfreg.align(scans, closure_pairs=-1)
    with pytest.raises(ValueError, match="at least two scans"):
        sdfreg.align(scans[:1])
    with pytest.raises(ValueError, match="align.anchor"):
        sdfreg.align(scans, anchor=5)
    with pytest.raises(ValueError, match=r"scans\[1\]"):
        sdfreg.align([scans[0], np.zeros((5, 2))])
    with pytest.raises(ValueError, match="align.init"):
        sdfreg.align(scans, init=[np.eye(4)])
    with pytest.raises(TypeError, match="scale"):
        sdfreg.align(scans, scale=True)
    for bad in ("up", "0,0,0", (1.0, 2.0), "nan,0,1", 3):
        with pytest.raises(ValueError, match="seen_from"):
            sdfreg.align(scans, seen_from=bad)
    with pytest.raises(ValueError, match="align.max_in_free_space"):
        sdfreg.align(scans, seen_from="origin", max_in_free_space=2.0)


def test_the_free_space_check_measures_every_edge_and_drops_none_when_allowed_everything() -> None:
    scans, _ = views(3, 2)
    plain = sdfreg.align(scans, **QUICK)
    assert all(e["in_free_space"] is None for e in plain.edges)
    for seen in ("origin", (0.0, 0.0, 1.0)):
        checked = sdfreg.align(scans, seen_from=seen, max_in_free_space=1.0, **QUICK)
        shares = [e["in_free_space"] for e in checked.edges if "registration" in e]
        assert shares and all(s is not None and 0.0 <= s <= 1.0 for s in shares), shares
        # Measuring changes no registration and, allowing everything, no pose.
        for a, b in zip(plain.poses, checked.poses):
            assert (a is None) == (b is None)
            if a is not None:
                assert np.array_equal(a, b)
