"""Many pairs on a Dask cluster (``pip install sdfreg[dask]``).

:func:`register_pairs` sends the pairs to the cluster in chunks, each chunk registered on one
worker by :func:`sdfreg.register_many`; every :class:`sdfreg.SdfModel` (and every target
array shared by several pairs) is scattered to the workers once instead of travelling with
each task. Results come back in input order, equal to :func:`sdfreg.register_many` on one
machine, a failed pair's exception in its slot::

    from dask.distributed import Client, LocalCluster
    import sdfreg, sdfreg.dask

    client = Client(LocalCluster(n_workers=4, threads_per_worker=1))
    model = sdfreg.fit(reference)                       # fitted once, here
    results = sdfreg.dask.register_pairs(client, [(scan, model) for scan in scans])

The same by hand, with ``client.map`` (each pair one task; the model scattered once)::

    remote = client.scatter(model, broadcast=True)
    futures = client.map(lambda scan, m: sdfreg.register(scan, m, threads=1), scans,
                         [remote] * len(scans))
    results = client.gather(futures)
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, Iterable, List, Optional, Sequence, Union

import sdfreg

if TYPE_CHECKING:  # pragma: no cover
    from distributed import Client

__all__ = ["register_pairs"]


def _register_chunk(pairs: Sequence[Any], threads: int, settings: dict[str, Any]) -> List[Any]:
    """Runs on a worker: one chunk of pairs through register_many."""
    return sdfreg.register_many(pairs, threads=threads, **settings)


def register_pairs(
    client: "Client",
    pairs: Iterable[Sequence[Any]],
    *,
    chunk_size: Optional[int] = None,
    threads_per_task: int = 1,
    **settings: Any,
) -> List[Union["sdfreg.Registration", Exception]]:
    """Registers ``pairs`` on the workers of ``client``, a ``dask.distributed.Client``.

    Args:
        client: The cluster's client.
        pairs: ``(source, target)`` or ``(source, target, init)`` as
            :func:`sdfreg.register_many` takes them; a target may be an :class:`sdfreg.SdfModel`.
            A model or target array that several pairs share (the same object) is scattered to
            the workers once.
        chunk_size: Pairs per task. Default: about four tasks per worker thread, so that a slow
            pair does not hold up the end of the batch.
        threads_per_task: Threads each task's ``register_many`` uses; the default 1 suits
            workers with one thread per core (Dask then runs one task per thread).
        **settings: The settings keywords of :func:`sdfreg.register` (``seed``, ``preset``,
            the settings groups …), the same for every pair.

    Returns:
        A list in the order of ``pairs``: :class:`sdfreg.Registration` or, for a pair that
        failed, its exception (as :func:`sdfreg.register_many` gives it, its message starting
        with ``pair i:`` where i counts within the task's chunk).

    Raises:
        ValueError: a setting is out of range (checked here, before anything is sent).
        TypeError: a keyword names no setting.
    """
    pairs = [tuple(p) if isinstance(p, (list, tuple)) else p for p in pairs]
    # Check the settings once here, before the cluster sees them: the same errors as locally.
    sdfreg.register_many([], threads=1, **settings)
    if not pairs:
        return []
    shared = _scatter_shared(client, pairs)
    pairs = [
        tuple(shared.get(id(part), part) for part in pair) if isinstance(pair, tuple) else pair
        for pair in pairs
    ]
    if chunk_size is None:
        workers = client.scheduler_info().get("workers", {})
        slots = max(1, sum(w.get("nthreads", 1) for w in workers.values()))
        chunk_size = max(1, math.ceil(len(pairs) / (4 * slots)))
    if chunk_size < 1:
        raise ValueError(f"chunk_size: must be ≥ 1, got {chunk_size}")
    chunks = [pairs[i : i + chunk_size] for i in range(0, len(pairs), chunk_size)]
    futures = [
        client.submit(_register_chunk, chunk, threads_per_task, settings, pure=False)
        for chunk in chunks
    ]
    results: List[Any] = []
    for chunk_results in client.gather(futures):
        results.extend(chunk_results)
    return results


def _scatter_shared(client: "Client", pairs: List[Any]) -> dict[int, Any]:
    """Futures of the models and of the target arrays that several pairs share, each
    scattered to every worker once, by the id of the object in ``pairs``."""
    counts: dict[int, int] = {}
    objects: dict[int, Any] = {}
    for pair in pairs:
        if isinstance(pair, tuple) and len(pair) >= 2:
            target = pair[1]
            counts[id(target)] = counts.get(id(target), 0) + 1
            objects[id(target)] = target
    shared = {
        key: obj
        for key, obj in objects.items()
        if isinstance(obj, sdfreg.SdfModel) or counts[key] > 1
    }
    if not shared:
        return {}
    keys = list(shared)
    futures = client.scatter([shared[k] for k in keys], broadcast=True, hash=False)
    return dict(zip(keys, futures))
