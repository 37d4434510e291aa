"""Every bad input raises the named exception with a message saying what and where; nothing
panics (a Rust panic would surface as pyo3's PanicException, which is no ValueError)."""

from __future__ import annotations

import json
import pickle
import warnings
from pathlib import Path

import numpy as np
import pytest

import sdfreg
from conftest import QUICK, blob


@pytest.fixture(scope="module")
def cloud() -> np.ndarray:
    return blob(500, np.random.default_rng(0))


def with_row(cloud: np.ndarray, row: int, value: float) -> np.ndarray:
    out = cloud.copy()
    out[row, 1] = value
    return out


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda c: c[:, :2], r"source: expected an \(N, 3\) array, got shape \(500, 2\)"),
        (lambda c: c.reshape(-1), r"source: expected an \(N, 3\) array, got shape \(1500,\)"),
        (lambda c: c[None], r"source: expected an \(N, 3\) array, got shape \(1, 500, 3\)"),
        (lambda c: c.astype(np.int32), "source: .*float32 or float64, got dtype int32"),
        (lambda c: c.astype(np.complex128), "got dtype complex128"),
        (lambda c: c.astype(str), "got dtype <U"),
        (lambda c: [[1.0, 2.0], [3.0]], r"source: expected an \(N, 3\) array of numbers"),
        (lambda c: "points.ply", r"source: expected an \(N, 3\) array"),
        (lambda c: with_row(c, 17, np.nan), "source cloud: point 17 has a non-finite coordinate"),
        (lambda c: with_row(c, 3, -np.inf), "source cloud: point 3 has a non-finite coordinate"),
        (lambda c: c[:9], "source cloud has 9 points; at least 10 are needed"),
        (lambda c: np.zeros((0, 3)), "source cloud has 0 points"),
        (
            lambda c: np.vstack([c[:8], np.zeros((40, 3))]),
            r"source cloud has 8 points besides 40 missing returns at exactly \(0, 0, 0\); at least 10",
        ),
        (lambda c: np.ones((50, 3)), "source cloud has no extent"),
        (lambda c: c * 1e12, r"source cloud's largest side, .*, is above the target's .* same units\?"),
    ],
)
def test_bad_source_raises_value_error(cloud, make, message) -> None:
    with pytest.raises(ValueError, match=message):
        sdfreg.register(make(cloud), cloud)


def test_a_stray_point_is_left_out(cloud) -> None:
    """One point 1000 times the cloud's size off the target and three missing returns in the
    source: left out, the same answer, each kind warned and counted."""
    stray = np.vstack([cloud, [[1000.0, 0.0, 0.0]]])
    moved = cloud @ np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]).T
    with_missing = np.vstack([moved, np.zeros((3, 3))])
    clean = sdfreg.register(moved, cloud)
    assert clean.points_left_out == {
        "source": {"missing_returns": 0, "stray": 0},
        "target": {"missing_returns": 0, "stray": 0},
    }
    with pytest.warns(UserWarning) as warned:
        r = sdfreg.register(with_missing, stray)
    assert [str(w.message) for w in warned] == [
        "source: 3 of 503 points are at exactly (0, 0, 0), a scanner's missing returns: left out",
        "target: 1 of 501 points lie more than 30 times as far from the cloud's middle as 99 % "
        "of them, stray returns: left out",
    ]
    np.testing.assert_array_equal(r.transformation, clean.transformation)
    assert r.fitness == clean.fitness
    assert r.points_left_out == {
        "source": {"missing_returns": 3, "stray": 0},
        "target": {"missing_returns": 0, "stray": 1},
    }
    assert pickle.loads(pickle.dumps(r)).points_left_out == r.points_left_out
    # A registration pickled before the counts existed reads them as zero.
    restore, (text,) = r.__reduce__()
    older = {k: v for k, v in json.loads(text).items() if not k.endswith("_left_out")}
    assert restore(json.dumps(older)).points_left_out == clean.points_left_out
    # A model's fit warns of the target's; registering against it, of the source's only; a
    # tracked frame's are counted without a warning.
    with pytest.warns(UserWarning, match="target: 1 of 501 points lie more than 30 times"):
        model = sdfreg.fit(stray)
    with pytest.warns(UserWarning, match="source: 3 of 503 points are at exactly") as warned:
        m = model.register(with_missing)
    assert len(warned) == 1
    assert m.points_left_out["source"] == {"missing_returns": 3, "stray": 0}
    assert m.points_left_out["target"] == {"missing_returns": 0, "stray": 0}
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        (t,) = model.track([with_missing], init=m.transformation)
    assert t.points_left_out["source"] == {"missing_returns": 3, "stray": 0}


def test_bad_target_is_named(cloud) -> None:
    with pytest.raises(ValueError, match="target cloud: point 2 has a non-finite"):
        sdfreg.register(cloud, with_row(cloud, 2, np.nan))
    with pytest.raises(ValueError, match=r"target: expected an \(N, 3\) array"):
        sdfreg.register(cloud, cloud.T)
    with pytest.raises(ValueError, match=r"source cloud's largest side, .*, is below the target's"):
        sdfreg.register(cloud, cloud * 1e12)


@pytest.mark.parametrize(
    "init, message",
    [
        (np.eye(3), r"init: expected a \(4, 4\) array, got shape \(3, 3\)"),
        (np.eye(4) * 2, "init: not a rigid transform"),
        (np.diag([1.0, 1.0, -1.0, 1.0]), "init: not a rigid transform"),
        (np.where(np.eye(4) > 0, np.nan, 0.0), "init: not a rigid transform"),
        (np.eye(4, dtype=np.int64), "init: .*got dtype int64"),
    ],
)
def test_bad_initial_guess(cloud, init, message) -> None:
    with pytest.raises(ValueError, match=message):
        sdfreg.register(cloud, cloud, init=init)


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda: sdfreg.CoarseToFineSettings(alternations=-1), "coarse_to_fine.alternations: must be a count ≥ 0, got -1"),
        (lambda: sdfreg.MlpSettings(beta=0.0), "invalid setting `mlp.beta`: must be a positive finite number, got 0"),
        (lambda: sdfreg.MlpSettings(width=0), "invalid setting `mlp.width`: must be ≥ 1, got 0"),
        (lambda: sdfreg.FitSettings(prefit_lr=0.0), "invalid setting `fit.prefit_lr`"),
        (lambda: sdfreg.LmSettings(max_tries=0), "invalid setting `lm.max_tries`: must be ≥ 1, got 0"),
        (lambda: sdfreg.LmSettings(rotation_tolerance=float("nan")), "`lm.rotation_tolerance`"),
        (lambda: sdfreg.MultistartSettings(keep=0), "invalid setting `multistart.keep`"),
        (lambda: sdfreg.MultistartSettings(points=-3), "multistart.points: must be a count"),
        (lambda: sdfreg.PolishSettings(neighbours=2), "invalid setting `polish.neighbours`: must be ≥ 3"),
        (lambda: sdfreg.PolishSettings(kernel_floor_spacings=-0.5), "invalid setting `polish.kernel_floor_spacings`: must be a finite number ≥ 0, got -0.5"),
        (lambda: sdfreg.ShiftSearchSettings(voxel=0.0), "invalid setting `shift_search.voxel`"),
        (lambda: sdfreg.RobustSettings(mode="fixed"), 'robust.scale: mode="fixed" needs a scale'),
        (lambda: sdfreg.RobustSettings(mode="fixed", scale=-0.1), "invalid setting `robust.mode.scale`"),
        (lambda: sdfreg.RobustSettings(scale=0.1), 'robust.scale: only with mode="fixed"'),
        (lambda: sdfreg.RobustSettings(mode="sometimes"), 'robust.mode: expected "auto", "on", "off" or "fixed"'),
        (lambda: sdfreg.RobustSettings(gain=0.5), "invalid setting `robust.mode.gain`"),
    ],
)
def test_bad_settings_objects_raise_value_error_naming_the_field(make, message) -> None:
    with pytest.raises(ValueError, match=message):
        make()


@pytest.mark.parametrize(
    "settings, message",
    [
        (dict(seed=-5), "seed: must be an integer ≥ 0"),
        (dict(inlier_distance=float("nan")), "invalid setting `inlier_distance`"),
        (dict(max_source_points=3), "invalid setting `max_source_points`: must be ≥ 10, got 3"),
        (dict(free_motion_ratio=1.5), "invalid setting `free_motion_ratio`"),
        (dict(preset="fast"), "preset: expected one of"),
        (dict(robust="sometimes"), 'robust.mode: expected "auto"'),
        (dict(robust=True), 'robust: expected "auto", "on", "off" or a RobustSettings, got True'),
    ],
)
def test_bad_settings(cloud, settings, message) -> None:
    with pytest.raises(ValueError, match=message):
        sdfreg.register(cloud, cloud, **settings)


def test_a_settings_object_of_the_wrong_group_is_a_type_error(cloud) -> None:
    with pytest.raises(TypeError, match="lm"):
        sdfreg.register(cloud, cloud, lm=sdfreg.FitSettings())  # type: ignore[arg-type]


@pytest.mark.parametrize(
    "settings",
    [
        dict(fit=sdfreg.FitSettings(prefit_steps=50, batch_surface=0)),
        dict(fit=sdfreg.FitSettings(prefit_steps=50, batch_source=0)),
        dict(fit=sdfreg.FitSettings(prefit_steps=50, sigma_neighbour=5000)),
        dict(fit=sdfreg.FitSettings(prefit_steps=50, query_pool=1)),
        dict(fit=sdfreg.FitSettings(prefit_steps=50, max_source_queries=1)),
        dict(fit=sdfreg.FitSettings(prefit_steps=50, lambda_surface=0.0, lambda_eikonal=0.0)),
        dict(multistart=sdfreg.MultistartSettings(points=1, hypotheses=1, keep=1)),
        dict(multistart=sdfreg.MultistartSettings(lm_steps=0, refine_steps=0)),
        dict(multistart=sdfreg.MultistartSettings(tie=0.0, distinct_rotation_deg=0.0)),
        dict(coarse_to_fine=sdfreg.CoarseToFineSettings(alternations=0)),
        dict(coarse_to_fine=sdfreg.CoarseToFineSettings(alternations=1, final_lm_steps=0)),
        dict(mlp=sdfreg.MlpSettings(depth=1, width=1)),
        dict(lm=sdfreg.LmSettings(lambda_decrease=1.0, lambda_increase=1.0)),
        dict(lm=sdfreg.LmSettings(rotation_tolerance=0.0, translation_tolerance=0.0)),
        dict(polish=sdfreg.PolishSettings(iterations=0)),
        dict(shift_search=sdfreg.ShiftSearchSettings(radius=0.0)),
        dict(robust=sdfreg.RobustSettings(mode="fixed", scale=1e-9)),
    ],
)
def test_extreme_settings_register_to_a_valid_pose(cloud, settings) -> None:
    """Edge values that pass validation run to a valid rigid pose."""
    merged = {**QUICK, **settings}
    if "fit" not in settings:
        merged["fit"] = sdfreg.FitSettings(prefit_steps=50, refine_steps=20)
    result = sdfreg.register(cloud, cloud, **merged)
    t = result.transformation
    assert np.isfinite(t).all()
    np.testing.assert_allclose(t[:3, :3].T @ t[:3, :3], np.eye(3), atol=1e-9)


def test_missing_file_is_file_not_found(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="missing.ply"):
        sdfreg.read_point_cloud(tmp_path / "missing.ply")


def test_directory_is_os_error(tmp_path: Path) -> None:
    (tmp_path / "d.ply").mkdir()
    with pytest.raises(OSError, match="d.ply"):
        sdfreg.read_point_cloud(tmp_path / "d.ply")


def test_unknown_extension_is_os_error(tmp_path: Path) -> None:
    (tmp_path / "a.obj").write_text("v 0 0 0\n")
    with pytest.raises(OSError, match=r"a.obj: unknown point-cloud format \"obj\""):
        sdfreg.read_point_cloud(tmp_path / "a.obj")


@pytest.mark.parametrize(
    "name, content, message",
    [
        ("empty.xyz", "", "no points found"),
        ("bad.xyz", "0 0 0\n1 2 x\n", "bad.xyz:2: "),
        ("short.xyz", "0 0 0\n1 2\n", "short.xyz:2: "),
        ("nan.xyz", "0 0 0\n1 nan 2\n", "nan.xyz:2: point 1 has a non-finite coordinate"),
        ("bad.ply", "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nend_header\n1\n",
         "bad.ply"),
        ("truncated.ply",
         "ply\nformat binary_little_endian 1.0\nelement vertex 5\nproperty float x\n"
         "property float y\nproperty float z\nend_header\n\x00\x00",
         "truncated.ply"),
    ],
)
def test_malformed_files_are_os_errors_naming_file_and_line(tmp_path, name, content, message):
    (tmp_path / name).write_bytes(content.encode("latin-1"))
    with pytest.raises(OSError, match=message):
        sdfreg.read_point_cloud(tmp_path / name)


def test_writing_bad_points_or_to_a_missing_folder(tmp_path: Path, cloud) -> None:
    with pytest.raises(ValueError, match="points: row 4 has a non-finite coordinate"):
        sdfreg.write_point_cloud(tmp_path / "a.ply", with_row(cloud, 4, np.inf))
    with pytest.raises(ValueError, match=r"points: expected an \(N, 3\) array"):
        sdfreg.write_point_cloud(tmp_path / "a.ply", cloud[:, :2])
    with pytest.raises(FileNotFoundError, match="no/such/folder/a.ply"):
        sdfreg.write_point_cloud(tmp_path / "no" / "such" / "folder" / "a.ply", cloud)
    with pytest.raises(OSError, match="unknown point-cloud format"):
        sdfreg.write_point_cloud(tmp_path / "a.obj", cloud)
    assert not (tmp_path / "a.ply").exists()
