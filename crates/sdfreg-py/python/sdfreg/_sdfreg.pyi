"""Native part of sdfreg (Rust, pyo3). Import from ``sdfreg``, not from here."""

import os
from typing import Dict, List, Optional, Union, final

import numpy as np
import numpy.typing as npt

__version__: str
__all__ = [
    "FreeMotion",
    "Registration",
    "__version__",
    "_core_defaults",
    "read_point_cloud",
    "register",
    "write_point_cloud",
]

_PathLike = Union[str, "os.PathLike[str]"]

@final
class FreeMotion:
    """A motion of the source that the clouds do not determine (relative constraint eigenvalue
    below ``free_motion_ratio``)."""

    @property
    def kind(self) -> str:
        """``"rotation"``, ``"translation"`` or ``"screw"``."""
    @property
    def axis(self) -> npt.NDArray[np.float64]:
        """Unit direction (3,), target frame: the rotation axis or the translation direction."""
    @property
    def point(self) -> npt.NDArray[np.float64]:
        """A point (3,) of the rotation axis, target frame, the clouds' units (for a
        translation, the moved source's centroid)."""
    @property
    def relative_eigenvalue(self) -> float:
        """The constraint eigenvalue relative to the largest (0 = unconstrained)."""

@final
class Registration:
    """The outcome of :func:`register`. Read-only."""

    @property
    def transformation(self) -> npt.NDArray[np.float64]:
        """4×4 array ``[R t; 0 1]`` mapping source coordinates into the target frame:
        ``p_target = R @ p_source + t``, in the clouds' units."""
    @property
    def converged(self) -> bool:
        """Whether the final Levenberg–Marquardt steps converged (see ``stop_reason``)."""
    @property
    def stop_reason(self) -> str:
        """``"small_step"``, ``"no_decrease"`` or ``"max_iterations"``."""
    @property
    def fitness(self) -> float:
        """Fraction of source points within ``inlier_distance`` of a target point."""
    @property
    def robust(self) -> bool:
        """Whether the robust kernel produced this result (``robust=True``, or least squares fitted
        below ``robust_below_fitness`` and the robust run fitted better)."""
    @property
    def inlier_rmse(self) -> float:
        """RMSE of the inliers' nearest-neighbour distances, in the clouds' units."""
    @property
    def inlier_distance(self) -> float:
        """The inlier distance used, in the clouds' units."""
    @property
    def iterations(self) -> int:
        """Levenberg–Marquardt iterations in total (the multi-start excluded)."""
    @property
    def cost(self) -> float:
        """Mean squared SDF value of the moved source points, in units squared."""
    @property
    def information(self) -> npt.NDArray[np.float64]:
        """6×6 ``JᵀJ`` at the result, in the target frame, twist order ``[ω (rad); v (units)]``
        about the target origin: the information matrix of a left perturbation of
        ``transformation``. Small eigenvalues mark poorly constrained directions."""
    @property
    def constraint_eigenvalues(self) -> npt.NDArray[np.float64]:
        """Eigenvalues (6, ascending) of the normalised constraint matrix, each divided by the
        largest: ``JᵀJ / N`` about the moved source's centroid, rotations scaled by its RMS radius.
        """
    @property
    def free_motions(self) -> List[FreeMotion]:
        """Motions the clouds leave (nearly) free, least constrained first — e.g. the spin of a
        bottle about its axis. The pose along them is arbitrary. Empty when the pose is fully
        determined."""
    @property
    def time_s(self) -> float:
        """Wall time of the registration, seconds."""

def register(
    source: npt.ArrayLike,
    target: npt.ArrayLike,
    *,
    init: Optional[npt.ArrayLike] = None,
    seed: int = 0,
    threads: int = 0,
    alternations: int = 10,
    lm_steps_per_alternation: int = 2,
    final_lm_steps: int = 10,
    multistart: bool = True,
    multistart_lm_steps: int = 5,
    multistart_offset: float = 0.1,
    multistart_points: int = 128,
    multistart_keep: int = 4,
    multistart_refine_steps: int = 15,
    multistart_truncation: float = 0.05,
    multistart_tie: float = 0.25,
    hypotheses: int = 3,
    free_motion_ratio: float = 0.002,
    max_source_points: int = 4096,
    max_target_points: int = 100000,
    robust_scale: Optional[float] = None,
    robust: bool = False,
    robust_below_fitness: float = 0.35,
    robust_kappa_start: float = 3.0,
    robust_kappa_end: float = 1.0,
    robust_floor: float = 0.002,
    inlier_distance: float = 0.02,
    width: int = 32,
    depth: int = 3,
    beta: float = 100.0,
    init_radius: float = 0.3,
    prefit_steps: int = 500,
    prefit_lr: float = 0.002,
    refine_steps: int = 40,
    refine_lr: float = 0.001,
    batch_queries: int = 1024,
    refine_batch_queries: int = 512,
    batch_source: int = 512,
    batch_surface: int = 512,
    query_pool: int = 16384,
    sigma_neighbour: int = 50,
    sigma_sample: int = 1024,
    lambda_surface: float = 0.1,
    lambda_eikonal: float = 0.001,
    max_source_queries: int = 16384,
    initial_lambda: float = 0.01,
    lambda_decrease: float = 3.0,
    lambda_increase: float = 4.0,
    max_tries: int = 6,
    rotation_tolerance: float = 1e-5,
    translation_tolerance: float = 1e-5,
    polish_iterations: int = 50,
    polish_neighbours: int = 5,
    polish_max_distance: float = 0.05,
    polish_max_shift: float = 0.05,
    polish_near_spacings: float = 3.0,
    shift_search_radius: float = 0.3,
    shift_search_voxel: float = 0.02,
    shift_search_candidates: int = 4,
    shift_search_min_gain: float = 0.02,
) -> Registration:
    """Registers ``source`` onto ``target``: finds the rigid transform that moves the source
    cloud onto the target's surface, without point correspondences.

    The target is represented by a small neural signed distance function Φ, fitted to it; the
    source is moved by Levenberg–Marquardt so that ``Σ Φ(R p + t)²`` is minimal, alternating
    with refinements of Φ near the moving source. Without ``init``, the centroids are aligned
    and the 24 rotations of the cube group (and small shifts) are tried, so any initial
    rotation works.

    Args:
        source: (N, 3) points to move; float32 or float64 array in any memory layout, or
            anything ``numpy.asarray`` turns into one (e.g. ``np.asarray(pcd.points)``).
        target: (M, 3) points that stay fixed, same units as ``source``.
        init: Optional 4×4 rigid initial guess mapping source into target; replaces the
            multi-start.
        seed: Seed of every random choice; equal seeds give identical results.
        threads: Worker threads; 0 = one per core. The result does not depend on it.

    The other keyword arguments are the engine's settings, with its defaults; lengths are
    fractions of the target's largest bounding-box side. ``alternations``,
    ``lm_steps_per_alternation``, ``final_lm_steps``: the coarse-to-fine schedule.
    ``multistart*``, ``hypotheses``: the initialisation. ``max_source_points``,
    ``max_target_points``: larger clouds are subsampled (seeded). ``free_motion_ratio``:
    constraint eigenvalues below it (relative) are reported as ``free_motions``. ``robust``:
    Geman–McClure kernel with the scale ``κ·median|Φ|`` (κ from ``robust_kappa_start`` to
    ``robust_kappa_end``, at least ``robust_floor``); ``robust_scale`` fixes the scale; without
    either, a result with ``fitness`` below ``robust_below_fitness`` is redone with the robust
    kernel (and ``multistart_tie`` 0.05), kept if it fits 1.3 times as many points. ``inlier_distance``: for ``fitness``
    and ``inlier_rmse``. ``width``, ``depth``, ``beta``, ``init_radius``: the SDF network.
    ``prefit_*``, ``refine_*``, ``batch_*``, ``query_pool``, ``sigma_*``, ``lambda_*``,
    ``max_source_queries``: the SDF fit. ``initial_lambda``, ``lambda_decrease``,
    ``lambda_increase``, ``max_tries``, ``*_tolerance``: the Levenberg–Marquardt solver.
    ``polish_*``: the final point-to-plane steps on the target points
    (``polish_iterations=0`` turns them off).
    ``shift_search_*``: translations (within ``shift_search_radius``, on a grid of
    ``shift_search_voxel``) that lay more source points onto the target than the SDF's pose; the
    best ``shift_search_candidates`` are polished, and one is kept if it raises the fitness by
    ``shift_search_min_gain`` (``shift_search_radius=0`` turns it off).

    Returns:
        The :class:`Registration`.

    Raises:
        ValueError: a cloud is not an (N, 3) float array, has a NaN or infinite coordinate,
            fewer than 10 points or no extent; ``init`` is not a rigid 4×4 transform; a
            setting is out of range.
    """

def read_point_cloud(path: _PathLike, *, drop_non_finite: bool = False) -> npt.NDArray[np.float64]:
    """Reads a point cloud as an (N, 3) float64 array.

    Formats by extension: ``.ply`` (ascii or binary, any numeric type; the ``vertex``
    element's x, y, z), ``.pcd`` (ascii, binary or binary_compressed; the x, y, z fields),
    ``.xyz``, ``.txt``, ``.csv``, ``.pts`` (first three columns).

    Args:
        path: The file.
        drop_non_finite: Drop points with a NaN or infinite coordinate (organised PCL clouds
            and range scanners mark missing returns that way) and warn how many, instead of
            raising.

    Raises:
        OSError: the file cannot be read (``FileNotFoundError``, ``PermissionError``, …), its
            format is unknown, or its contents are malformed; the message names the file and,
            for text, the line.
    """

def write_point_cloud(path: _PathLike, points: npt.ArrayLike) -> None:
    """Writes (N, 3) finite points; the format follows the extension (``.ply``: binary
    float64; text formats: one ``x y z`` line per point, full precision). An existing file is
    replaced.

    Raises:
        ValueError: ``points`` is not an (N, 3) float array or has a non-finite coordinate.
        OSError: the file cannot be written or the extension is unknown.
    """

def _core_defaults() -> Dict[str, Union[int, float, bool, None]]:
    """The engine's defaults of the settings :func:`register` takes (for tests)."""
