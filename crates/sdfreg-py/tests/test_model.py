"""The fitted target as a model: fit once, register many, query, save, load and pickle."""

from __future__ import annotations

import pickle
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest

import sdfreg
from conftest import QUICK, blob, paper_pair, pose_errors

FIT = sdfreg.FitSettings(prefit_steps=150, model_prefit_steps=150, refine_steps=20)


@pytest.fixture(scope="module")
def pair() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return paper_pair(21)


@pytest.fixture(scope="module")
def model(pair) -> sdfreg.SdfModel:
    _, target, _ = pair
    return sdfreg.fit(target, fit=FIT)


def test_registering_against_a_model_is_accurate_and_refining_equals_the_cloud(pair, model) -> None:
    source, target, truth = pair
    frozen = sdfreg.register(source, model, **QUICK)
    rot, trans = pose_errors(frozen.transformation, truth)
    assert rot < 1.0 and trans < 0.01, (rot, trans)
    np.testing.assert_array_equal(model.register(source, **QUICK).transformation, frozen.transformation)
    refined = sdfreg.register(source, model, refine=True, **QUICK)
    direct = sdfreg.register(source, target, **QUICK)
    np.testing.assert_array_equal(refined.transformation, direct.transformation)
    assert refined.stages == direct.stages
    # Where the time went: against a model nothing is pre-fitted; a full call pre-fits Φ.
    names = ["prefit", "initial", "coarse_to_fine", "final_lm", "polish", "shift_search",
             "measure", "other_run"]
    assert list(frozen.stage_times_s) == list(direct.stage_times_s) == names
    assert frozen.stage_times_s["prefit"] == 0.0 and direct.stage_times_s["prefit"] > 0.0
    assert sum(direct.stage_times_s.values()) <= direct.time_s
    with pytest.raises(ValueError, match="refine: False needs an SdfModel target"):
        sdfreg.register(source, target, refine=False, **QUICK)


def test_queries_are_in_the_targets_units(model) -> None:
    pts = model.target_points
    assert pts.shape[1] == 3 and len(pts) == 1024
    d = model.distance(pts)
    assert d.shape == (len(pts),) and np.median(np.abs(d)) < 0.01
    # 2 % of the extent out along ∇Φ: Φ grows by that much (an SDF's gradient has unit length).
    off = pts + 0.02 * model.gradient(pts)
    err = np.abs(model.distance(off) - (d + 0.02))
    assert np.median(err) < 0.002 and np.quantile(err, 0.95) < 0.006, (np.median(err), np.quantile(err, 0.95))
    back = model.closest_points(off)
    assert np.median(np.linalg.norm(back - pts, axis=1)) < 0.01
    with pytest.raises(ValueError, match="points: row 1 has a non-finite coordinate"):
        model.distance(np.array([[0.0, 0, 0], [np.nan, 0, 0]]))


def test_save_load_and_pickle_are_bit_identical(pair, model, tmp_path: Path) -> None:
    source, _, _ = pair
    path = tmp_path / "m.sdfm"
    model.save(path)
    assert path.read_bytes() == model.to_bytes()
    loaded = sdfreg.load_model(path)
    unpickled = pickle.loads(pickle.dumps(model))
    base = sdfreg.register(source, model, **QUICK)
    for other in (loaded, unpickled):
        r = sdfreg.register(source, other, **QUICK)
        np.testing.assert_array_equal(r.transformation, base.transformation)
        assert r.stages == base.stages
    assert repr(loaded).startswith("SdfModel(1024 target points")


def test_the_file_opens_without_sdfreg(model, tmp_path: Path) -> None:
    """The layout the docs state: a safetensors file, read here by hand with numpy."""
    import json
    import struct

    data = model.to_bytes()
    (n,) = struct.unpack("<Q", data[:8])
    header = json.loads(data[8 : 8 + n])
    meta = json.loads(header["__metadata__"]["sdfreg"])
    assert meta["format"] == "sdfreg-model" and meta["version"] == 1
    info = header["target.points"]
    start, end = info["data_offsets"]
    pts = np.frombuffer(data[8 + n + start : 8 + n + end], "<f4").reshape(info["shape"])
    (scale,) = np.frombuffer(data[8 + n + header["frame.scale"]["data_offsets"][0] :][:8], "<f8")
    c0 = header["frame.centre"]["data_offsets"][0]
    centre = np.frombuffer(data[8 + n + c0 : 8 + n + c0 + 24], "<f8")
    np.testing.assert_allclose(pts * scale + centre, model.target_points, atol=1e-6)


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda b: b[: len(b) // 2], "truncated"),
        (lambda b: b[:-1] + bytes([b[-1] ^ 1]), "corrupted: the checksum does not match"),
        (lambda b: b"ply\nformat ascii 1.0\n", "not a model file"),
        (lambda b: b"", "truncated"),
    ],
)
def test_bad_model_files_raise_oserror_naming_the_file(model, tmp_path: Path, make, message) -> None:
    path = tmp_path / "bad.sdfm"
    path.write_bytes(make(model.to_bytes()))
    with pytest.raises(OSError, match=f"bad.sdfm: .*{message}"):
        sdfreg.load_model(path)
    with pytest.raises(FileNotFoundError):
        sdfreg.load_model(tmp_path / "missing.sdfm")


def test_threads_share_one_model(pair, model) -> None:
    source, _, _ = pair
    rng = np.random.default_rng(2)
    sources = [source + rng.normal(0, 1e-3, source.shape) for _ in range(4)]
    alone = [sdfreg.register(s, model, **QUICK).transformation for s in sources]
    with ThreadPoolExecutor(4) as pool:
        together = list(pool.map(lambda s: sdfreg.register(s, model, **QUICK).transformation, sources))
    for a, b in zip(alone, together):
        np.testing.assert_array_equal(a, b)


def test_fit_refuses_bad_targets() -> None:
    with pytest.raises(ValueError, match="target cloud has 5 points"):
        sdfreg.fit(blob(5, np.random.default_rng(0)))
    with pytest.raises(ValueError, match="seed: must be an integer ≥ 0"):
        sdfreg.fit(blob(50, np.random.default_rng(0)), seed=-1)


def test_the_mesh_is_a_closed_surface_near_the_target(model) -> None:
    vertices, faces = model.mesh(resolution=48)
    assert vertices.dtype == np.float64 and faces.dtype == np.int64 and faces.shape[1] == 3
    assert len(faces) > 500 and faces.min() >= 0 and faces.max() < len(vertices)
    # Every vertex lies on Φ's zero level set (to a fraction of a grid cell).
    assert np.quantile(np.abs(model.distance(vertices)), 0.95) < 1.0 / 48
    # Closed: every edge is shared by exactly two faces.
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert (counts == 2).mean() > 0.99
    with pytest.raises(ValueError, match="resolution"):
        model.mesh(resolution=2)


def test_tracking_warm_starts_each_frame_and_reports_bad_frames(pair, model) -> None:
    source, _, truth = pair
    frames = []
    for k in range(6):
        a = np.radians(2.0 * k)
        step = np.eye(4)
        step[:3, :3] = [[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]]
        frames.append((source - step[:3, 3]) @ step[:3, :3])  # the source turned back by 2k°
    frames.insert(3, np.full((5, 3), np.nan))
    results = model.track(frames, init=truth)
    assert isinstance(results[3], ValueError) and "frames[3]" in str(results[3])
    good = [r for r in results if isinstance(r, sdfreg.Registration)]
    assert len(good) == 6
    for k, r in enumerate(good):
        a = np.radians(2.0 * k)
        step = np.eye(4)
        step[:3, :3] = [[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]]
        rot, trans = pose_errors(r.transformation, truth @ step)
        assert rot < 0.5 and trans < 0.005, (k, rot, trans)
        assert r.stages["initial"]["given"] and r.stages["initial"]["starts"] == 0


def test_a_registration_pickles_exactly() -> None:
    """Results come back from worker processes whole: pose, matrices, free motions, stages."""
    rng = np.random.default_rng(3)
    h, t = rng.uniform(-0.4, 0.4, 2000), rng.uniform(0, 2 * np.pi, 2000)
    tube = np.column_stack([0.15 * np.cos(t), 0.15 * np.sin(t), h])  # a free spin to carry
    r = sdfreg.register(tube + [0.03, -0.02, 0.01], tube, **QUICK)
    back = pickle.loads(pickle.dumps(r))
    np.testing.assert_array_equal(back.transformation, r.transformation)
    np.testing.assert_array_equal(back.information, r.information)
    np.testing.assert_array_equal(back.constraint_eigenvalues, r.constraint_eigenvalues)
    assert [f.kind for f in back.free_motions] == [f.kind for f in r.free_motions] == ["rotation"]
    np.testing.assert_array_equal(back.free_motions[0].axis, r.free_motions[0].axis)
    assert (back.stages, back.fitness, back.cost, back.time_s, back.stop_reason) == (
        r.stages, r.fitness, r.cost, r.time_s, r.stop_reason)
    assert back.stage_times_s == r.stage_times_s and r.stage_times_s["prefit"] > 0.0
    with pytest.raises(ValueError, match="not a pickled Registration"):
        sdfreg._sdfreg._registration_from_json("{}")


def test_a_local_model_is_chosen_by_name_and_round_trips(pair) -> None:
    """``model="local"``: the MLP plus a sparse grid of corrections near the target's points;
    the kind, voxel and corrections survive pickling, and so do registrations against it."""
    source, target, truth = pair
    local = sdfreg.fit(target, fit=FIT, model="local")
    assert local.kind == "local" and local.local_parameters > 0
    # The voxel: at least 1/128 of the target's largest side, in the target's units.
    extent = float((target.max(0) - target.min(0)).max())
    assert local.voxel is not None and local.voxel >= extent / 128 * (1 - 1e-6)
    assert "local grid of" in repr(local)
    auto = sdfreg.fit(target, fit=FIT)
    assert auto.kind == "global" and auto.voxel is None and auto.local_parameters == 0
    r = sdfreg.register(source, local, **QUICK)
    rot, trans = pose_errors(r.transformation, truth)
    assert rot < 1.0 and trans < 0.01, (rot, trans)
    back = pickle.loads(pickle.dumps(local))
    assert (back.kind, back.voxel, back.local_parameters) == (local.kind, local.voxel, local.local_parameters)
    np.testing.assert_array_equal(sdfreg.register(source, back, **QUICK).transformation, r.transformation)
    np.testing.assert_array_equal(back.distance(target[:50]), local.distance(target[:50]))
    # Registering against the cloud with model="local" fits the same kind.
    direct = sdfreg.register(source, target, model="local", **QUICK)
    rot, trans = pose_errors(direct.transformation, truth)
    assert rot < 1.0 and trans < 0.01, (rot, trans)


def test_a_local_voxel_in_the_targets_units(pair) -> None:
    """``LocalSettings(voxel_size=…)``: the voxel in the target's units, whatever its extent; it
    makes ``"auto"`` local, survives pickling, and one finer than the points or larger than the target is refused
    naming ``fit.local.voxel_size``."""
    _, target, _ = pair
    extent = float((target.max(0) - target.min(0)).max())
    for units in (1.0, 1000.0):  # the same cloud in metres and in millimetres
        size = 0.05 * extent * units
        model = sdfreg.fit(target * units, fit=sdfreg.FitSettings(
            prefit_steps=50, local=sdfreg.LocalSettings(voxel_size=size)))
        assert model.kind == "local" and abs(model.voxel - size) < 1e-6 * size, (model.voxel, size)
        back = pickle.loads(pickle.dumps(model))
        assert back.voxel == model.voxel and back.local_parameters == model.local_parameters
    with pytest.raises(ValueError, match=r"invalid setting `fit.local.voxel_size`: a local voxel of"):
        sdfreg.fit(target, fit=sdfreg.FitSettings(local=sdfreg.LocalSettings(voxel_size=1e-7 * extent)))
    with pytest.raises(ValueError, match=r"`fit.local.voxel_size`: .* above the target's largest side"):
        sdfreg.fit(target, fit=sdfreg.FitSettings(local=sdfreg.LocalSettings(voxel_size=2.0 * extent)))
    with pytest.raises(ValueError, match="fit.local.voxel_size"):
        sdfreg.LocalSettings(voxel_size=-1.0)
    with pytest.raises(ValueError, match="fit.local.global_rerun_below_fitness"):
        sdfreg.LocalSettings(global_rerun_below_fitness=1.5)
    assert sdfreg.LocalSettings().global_rerun_below_fitness == 0.35


def test_a_local_grid_too_fine_or_too_large_is_a_value_error(pair) -> None:
    """A voxel below half the point spacing, or a grid above ``max_memory_mib``, is refused
    with a ``ValueError`` naming the setting and saying what it would have been."""
    source, target, _ = pair
    fine = sdfreg.FitSettings(local=sdfreg.LocalSettings(kind="local", cells=1_000_000, spacings=0.0))
    with pytest.raises(ValueError, match=r"invalid setting `fit.local.cells`: a local voxel of 1\.000e-6"):
        sdfreg.fit(target, fit=fine)
    with pytest.raises(ValueError, match="use a voxel of at least"):
        sdfreg.register(source, target, fit=fine)
    small = sdfreg.FitSettings(local=sdfreg.LocalSettings(kind="local", max_memory_mib=0.01))
    with pytest.raises(ValueError, match=r"corrections \(≈ [0-9.]+ MiB\), above fit.local.max_memory_mib = 0.01 MiB"):
        sdfreg.fit(target, fit=small)
    with pytest.raises(ValueError, match="fit.local.max_memory_mib"):
        sdfreg.LocalSettings(max_memory_mib=0.0)


@pytest.mark.parametrize("call", ["fit", "register", "register_many"])
def test_an_unknown_model_kind_is_a_value_error(pair, call) -> None:
    source, target, _ = pair
    with pytest.raises(ValueError, match=r'model: expected one of \["auto", "global", "local"\], got "scene"'):
        if call == "fit":
            sdfreg.fit(target, model="scene")
        elif call == "register":
            sdfreg.register(source, target, model="scene")
        else:
            sdfreg.register_many([(source, target)], model="scene")


def test_a_source_fitting_a_local_model_poorly_warns_naming_the_global_kind(pair) -> None:
    """A full call would run again with a global Φ; a stored local model cannot, and says so."""
    import warnings

    _, target, _ = pair
    scattered = np.random.default_rng(4).uniform(-1.0, 1.0, (600, 3)) * np.ptp(target, axis=0) / 2
    scattered += target.mean(axis=0)
    local = sdfreg.fit(target, model="local", fit=sdfreg.FitSettings(model_prefit_steps=200))
    glob = sdfreg.fit(target, model="global", fit=sdfreg.FitSettings(model_prefit_steps=200))
    with pytest.warns(UserWarning, match=r"fits 0\.[0-9]+ of a local \(scene\) model.*model=\"global\""):
        r = sdfreg.register(scattered, local)
    assert r.fitness < 0.35
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sdfreg.register(scattered, glob)
        sdfreg.register(target, local)
