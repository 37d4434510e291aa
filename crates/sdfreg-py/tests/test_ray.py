"""Ray Data's map_batches with sdfreg.ray.RegisterBatch (the model fitted once per actor);
run when Ray is installed (scripts/python-env tries), usage statistics off."""

from __future__ import annotations

import os

import numpy as np
import pytest

import sdfreg
from conftest import QUICK, paper_pair
from sdfreg.ray import RegisterBatch


@pytest.fixture(scope="module")
def scans() -> tuple[np.ndarray, list[np.ndarray]]:
    target = paper_pair(80, n=600)[1]
    sources = [paper_pair(80 + k, n=600)[0] for k in range(1)]
    # Independent copies of the target, moved: every source belongs to the same target.
    rng = np.random.default_rng(3)
    for k in range(5):
        angle = 0.2 + 0.1 * k
        c, s = np.cos(angle), np.sin(angle)
        rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
        sources.append(target[rng.permutation(len(target))] @ rot.T + 0.05 * k)
    sources.append(np.full((3, 3), 1.0))  # too few points: its error in its row
    return target, sources


def test_register_batch_without_ray_equals_register_many(scans) -> None:
    target, sources = scans
    call = RegisterBatch(target, **QUICK)
    out = call({"source": np.array(sources, dtype=object)})
    local = sdfreg.register_many([(s, call.model) for s in sources], **QUICK)
    for k, r in enumerate(local):
        if isinstance(r, Exception):
            assert "has 3 points" in out["error"][k] and np.isnan(out["transformation"][k]).all()
        else:
            assert out["error"][k] == ""
            np.testing.assert_array_equal(out["transformation"][k], r.transformation)
    with pytest.raises(ValueError, match="invalid setting `lm.max_tries`"):
        RegisterBatch(call.model, lm=sdfreg.LmSettings(max_tries=0))


def test_ray_data_map_batches_with_an_actor_per_core(scans, tmp_path) -> None:
    os.environ["RAY_USAGE_STATS_ENABLED"] = "0"
    ray = pytest.importorskip("ray")
    target, sources = scans
    model_path = tmp_path / "target.sdfm"
    sdfreg.fit(target, fit=QUICK["fit"]).save(model_path)
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, ignore_reinit_error=True)
    try:
        ds = ray.data.from_items([{"row": k, "source": s} for k, s in enumerate(sources)])
        rows = ds.map_batches(
            RegisterBatch,
            fn_constructor_args=(str(model_path),),
            fn_constructor_kwargs=QUICK,
            concurrency=2,
            batch_size=2,
            batch_format="numpy",
        ).take_all()
    finally:
        ray.shutdown()
    model = sdfreg.load_model(model_path)
    rows.sort(key=lambda r: r["row"])
    assert [r["row"] for r in rows] == list(range(len(sources)))
    for r, s in zip(rows, sources):
        if len(s) < 10:
            assert "has 3 points" in r["error"]
            continue
        alone = sdfreg.register(s, model, **QUICK)
        np.testing.assert_array_equal(r["transformation"], alone.transformation)
