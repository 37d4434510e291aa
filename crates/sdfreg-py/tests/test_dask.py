"""Many pairs on a Dask LocalCluster (two worker processes): results identical to
register_many, models scattered once, arrays that arrive by pickle accepted."""

from __future__ import annotations

import numpy as np
import pytest

import sdfreg
from conftest import QUICK, paper_pair

distributed = pytest.importorskip("distributed")
import sdfreg.dask  # noqa: E402


@pytest.fixture(scope="module")
def client():
    cluster = distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    )
    with distributed.Client(cluster) as c:
        yield c
    cluster.close()


@pytest.fixture(scope="module")
def pairs() -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    return [paper_pair(60 + k, n=600) for k in range(4)]


def test_register_pairs_equals_register_many_and_keeps_failures_in_their_slot(client, pairs) -> None:
    model = sdfreg.fit(pairs[0][1], fit=QUICK["fit"])
    batch: list[tuple] = [(s, t) for s, t, _ in pairs]
    batch += [(s, model) for s, _, _ in pairs]
    batch.insert(3, (pairs[0][0][:3], pairs[0][1]))  # too few points
    remote = sdfreg.dask.register_pairs(client, batch, chunk_size=2, seed=5, **QUICK)
    local = sdfreg.register_many(batch, seed=5, **QUICK)
    assert len(remote) == len(local) == 9
    for r, l in zip(remote, local):
        if isinstance(l, Exception):
            assert type(r) is type(l) and "has 3 points; at least 10 are needed" in str(r)
            continue
        np.testing.assert_array_equal(r.transformation, l.transformation)
        assert r.stages == l.stages and r.fitness == l.fitness
    # The model and the target shared by two pairs go to the workers once, as scattered
    # objects on every worker; a target used once travels with its task.
    (s0, t0, _), (s1, _, _), (s2, t2, _), (s3, _, _) = pairs
    shared = sdfreg.dask._scatter_shared(client, [(s0, model), (s1, model), (s2, t2), (s3, t0), (s1, t0)])
    assert set(shared) == {id(model), id(t0)}
    assert all(isinstance(f, distributed.Future) for f in shared.values())
    assert all(len(holders) == 2 for holders in client.who_has(list(shared.values())).values())
    with pytest.raises(ValueError, match="invalid setting `lm.max_tries`"):
        sdfreg.dask.register_pairs(client, batch, lm=sdfreg.LmSettings(max_tries=0))
    assert sdfreg.dask.register_pairs(client, []) == []


def test_a_plain_client_map_of_register_works_on_pickled_arrays(client, pairs) -> None:
    """What a new user tries first: each pair pickled to a worker process, registered there.
    Arrays that arrive by pickle may be misaligned or read-only; they are accepted."""
    batch = [(s, t) for s, t, _ in pairs[:2]]
    futures = client.map(lambda p: sdfreg.register(*p, threads=1, **QUICK), batch)
    remote = client.gather(futures)
    for (s, t), r in zip(batch, remote):
        alone = sdfreg.register(s, t, **QUICK)
        np.testing.assert_array_equal(r.transformation, alone.transformation)
