"""register_many: many pairs on every core, each equal to register alone, errors in their slots."""

from __future__ import annotations

import numpy as np
import pytest

import sdfreg
from conftest import QUICK, paper_pair
from test_register import misaligned


@pytest.fixture(scope="module")
def pairs() -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    return [paper_pair(40 + k, n=600) for k in range(3)]


@pytest.fixture(scope="module")
def model(pairs) -> sdfreg.SdfModel:
    return sdfreg.fit(pairs[0][1], fit=QUICK["fit"])


def test_each_result_equals_registering_the_pair_alone_and_failures_stay_in_their_slot(pairs, model) -> None:
    (s0, t0, truth0), (s1, t1, _), (s2, _, _) = pairs
    init = np.linalg.inv(truth0) @ truth0  # the identity, as a 4×4 guess
    batch = [
        (s0, t0),
        (s1, t1, None),
        (s0[:4], t0),  # too few points: fails alone
        (misaligned(s2), model),  # a pickled-array layout, against a model
        [s0, t0, init],
        "not a pair",
        (s1, t1, np.eye(3)),  # a bad guess: fails alone
    ]
    calls: list[tuple[int, int]] = []
    results = sdfreg.register_many(batch, threads=2, seed=3, progress=lambda d, n: calls.append((d, n)), **QUICK)
    assert len(results) == len(batch)
    alone = [
        sdfreg.register(s0, t0, seed=3, **QUICK),
        sdfreg.register(s1, t1, seed=3, **QUICK),
        None,
        sdfreg.register(s2, model, seed=3, **QUICK),
        sdfreg.register(s0, t0, init=init, seed=3, **QUICK),
    ]
    for k in (0, 1, 3, 4):
        r = results[k]
        assert isinstance(r, sdfreg.Registration), r
        np.testing.assert_array_equal(r.transformation, alone[k].transformation)
        assert r.stages == alone[k].stages
    for k, message in [
        (2, "pair 2: source cloud has 4 points; at least 10 are needed"),
        (5, "pair 5: pair: expected (source, target) or (source, target, init), got 'not a pair'"),
        (6, "pair 6: init: "),
    ]:
        assert isinstance(results[k], ValueError), results[k]
        assert str(results[k]).startswith(message), str(results[k])
    # Progress: the pairs that could not be read count at once, then one call per pair run.
    assert calls[0] == (2, 7) and calls[-1] == (7, 7)
    assert [d for d, _ in calls] == list(range(2, 8))


def test_bad_settings_and_arguments_raise_before_any_pair_runs(pairs) -> None:
    s, t, _ = pairs[0]
    with pytest.raises(ValueError, match="invalid setting `lm.max_tries`"):
        sdfreg.register_many([(s, t)], lm=sdfreg.LmSettings(max_tries=0))
    with pytest.raises(TypeError, match="register_many\\(\\) got an unexpected keyword argument 'max_iterations'"):
        sdfreg.register_many([(s, t)], max_iterations=3)
    with pytest.raises(TypeError, match="expected a LmSettings or None, got dict"):
        sdfreg.register_many([(s, t)], lm={"max_tries": 3})
    with pytest.raises(ValueError, match="progress: expected True, False or a callable"):
        sdfreg.register_many([(s, t)], progress="yes")
    with pytest.raises(ValueError, match="threads: must be a count ≥ 0, got -1"):
        sdfreg.register_many([(s, t)], threads=-1)
    with pytest.raises(TypeError):
        sdfreg.register_many(3)  # type: ignore[arg-type]
    assert sdfreg.register_many([]) == []


def test_an_exception_in_progress_stops_the_batch_early(pairs, model) -> None:
    s, _, _ = pairs[0]
    seen: list[int] = []

    def interrupt(done: int, total: int) -> None:
        seen.append(done)
        if done == 1:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        sdfreg.register_many([(s, model)] * 12, threads=1, progress=interrupt, **QUICK)
    # One worker: the pair running when it was stopped finishes, no other starts.
    assert seen == [0, 1]


def test_progress_true_draws_a_bar_on_stderr(pairs, model, capsys, monkeypatch) -> None:
    import sys

    monkeypatch.setitem(sys.modules, "tqdm", None)  # the plain bar, whether tqdm is installed or not
    monkeypatch.setitem(sys.modules, "tqdm.auto", None)
    s, _, _ = pairs[0]
    sdfreg.register_many([(s, model)] * 2, progress=True, **QUICK)
    err = capsys.readouterr().err
    assert "register_many: 2/2 pairs" in err and "pairs/s" in err, err


def test_settings_objects_pickle_exactly() -> None:
    import pickle

    objects = [
        sdfreg.FitSettings(prefit_steps=123, prefit_lr=0.0031),
        sdfreg.MlpSettings(width=16),
        sdfreg.RobustSettings(mode="fixed", scale=0.02),
        sdfreg.RobustSettings(mode="auto", below_fitness=0.5),
        sdfreg.LmSettings(max_tries=7),
        sdfreg.MultistartSettings(enabled=False),
        sdfreg.CoarseToFineSettings(alternations=2),
        sdfreg.PolishSettings(),
        sdfreg.ShiftSearchSettings(),
    ]
    for o in objects:
        back = pickle.loads(pickle.dumps(o))
        assert type(back) is type(o) and back == o and repr(back) == repr(o)
    with pytest.raises(ValueError, match="invalid setting `lm.max_tries`"):
        _, (name, json) = objects[4].__reduce__()
        sdfreg._sdfreg._settings_from_json(name, json.replace('"max_tries":7', '"max_tries":0'))
    with pytest.raises(ValueError, match='no settings class "Nope"'):
        sdfreg._sdfreg._settings_from_json("Nope", "{}")
