"""Many sources against one target with Ray Data (``pip install sdfreg[ray]``).

:class:`RegisterBatch` is the callable class ``Dataset.map_batches`` wants: each actor fits
the target's model once in ``__init__`` (or loads a saved ``.sdfm``, or takes a fitted
:class:`sdfreg.SdfModel`, which pickles), then registers every batch of sources against it::

    import os
    os.environ["RAY_USAGE_STATS_ENABLED"] = "0"   # no usage statistics sent
    import ray, sdfreg
    from sdfreg.ray import RegisterBatch

    ds = ray.data.from_items([{"source": scan} for scan in scans])
    out = ds.map_batches(RegisterBatch, fn_constructor_args=(reference,), concurrency=2,
                         batch_size=8, batch_format="numpy").take_all()
    # out[i]["transformation"]: the 4×4 mapping scan i into the reference's frame;
    # out[i]["error"]: "" or why that scan failed.

Nothing here imports Ray: the class is plain numpy in, numpy out.
"""

from __future__ import annotations

import os
from typing import Any, Dict, Union

import numpy as np
import numpy.typing as npt

import sdfreg

__all__ = ["RegisterBatch"]


class RegisterBatch:
    """Registers batches of sources against one target, fitted once per instance.

    Args:
        target: The target: an (M, 3) cloud (fitted here, once), an :class:`sdfreg.SdfModel`,
            or the path of a saved model (``.sdfm``).
        threads: Threads each batch's :func:`sdfreg.register_many` uses; 0 = one per core
            (one actor per machine), 1 when Ray runs an actor per core.
        **settings: The settings keywords of :func:`sdfreg.register`, for the fit and for
            every registration.
    """

    def __init__(
        self,
        target: Union[npt.ArrayLike, "sdfreg.SdfModel", str, "os.PathLike[str]"],
        *,
        threads: int = 1,
        **settings: Any,
    ) -> None:
        if isinstance(target, sdfreg.SdfModel):
            self.model = target
        elif isinstance(target, (str, os.PathLike)):
            self.model = sdfreg.load_model(target)
        else:
            fit_keys = {"seed", "max_target_points", "mlp", "fit"}
            fit_settings = {k: v for k, v in settings.items() if k in fit_keys}
            self.model = sdfreg.fit(target, threads=threads, **fit_settings)
        self.threads = threads
        self.settings = settings
        # The settings are checked now, not at the first batch.
        sdfreg.register_many([], **settings)

    def __call__(self, batch: Dict[str, Any]) -> Dict[str, np.ndarray]:
        """``batch["source"]``: the sources (a sequence of (N, 3) arrays; an ``init`` column of
        4×4 guesses is used when present). Returns the batch's other columns (ids, paths…) as
        they came, the sources left out, and ``transformation`` (B, 4, 4), ``fitness``,
        ``inlier_rmse``, ``converged`` (B,) and ``error`` (B,) strings, empty when the source
        registered."""
        sources = list(batch["source"])
        inits = list(batch["init"]) if "init" in batch else [None] * len(sources)
        pairs = [(np.asarray(s).reshape(-1, 3), self.model, i) for s, i in zip(sources, inits)]
        results = sdfreg.register_many(pairs, threads=self.threads, **self.settings)
        n = len(results)
        out: Dict[str, np.ndarray] = {k: np.asarray(v) for k, v in batch.items() if k != "source"}
        out |= {
            "transformation": np.full((n, 4, 4), np.nan),
            "fitness": np.zeros(n),
            "inlier_rmse": np.full(n, np.nan),
            "converged": np.zeros(n, dtype=bool),
            "error": np.array([""] * n, dtype=object),
        }
        for k, r in enumerate(results):
            if isinstance(r, Exception):
                out["error"][k] = str(r)
                continue
            out["transformation"][k] = r.transformation
            out["fitness"][k] = r.fitness
            out["inlier_rmse"][k] = r.inlier_rmse
            out["converged"][k] = r.converged
        return out
