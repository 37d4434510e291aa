"""Native part of sdfreg (Rust, pyo3). Import from ``sdfreg``, not from here."""

import os
from typing import (
    Any,
    Callable,
    Dict,
    Iterable,
    List,
    Optional,
    Protocol,
    Tuple,
    Sequence,
    Union,
    final,
)

from typing_extensions import TypedDict, Unpack

import numpy as np
import numpy.typing as npt

__version__: str
__all__ = [
    "Alignment",
    "CoarseToFineSettings",
    "Evaluation",
    "FitSettings",
    "FreeMotion",
    "LmSettings",
    "LocalSettings",
    "MlpSettings",
    "MultistartSettings",
    "PolishSettings",
    "Registration",
    "RobustSettings",
    "SdfModel",
    "MeshModel",
    "ShiftSearchSettings",
    "__version__",
    "_model_from_bytes",
    "_registration_from_json",
    "_evaluation_from_json",
    "_settings_from_json",
    "_settings_keywords",
    "align",
    "evaluate_registration",
    "fit",
    "load_model",
    "mesh_model",
    "read_mesh",
    "_mesh_model_from_parts",
    "_core_defaults",
    "read_e57_scans",
    "read_point_cloud",
    "read_poses",
    "register",
    "register_many",
    "write_e57_scans",
    "write_moved_point_cloud",
    "write_point_cloud",
]

_PathLike = Union[str, "os.PathLike[str]"]

class _HasPoints(Protocol):
    """A point cloud object such as Open3D's ``PointCloud``: ``np.asarray(obj.points)`` is (N, 3)."""

    @property
    def points(self) -> npt.ArrayLike: ...

@final
class MlpSettings:
    """The SDF network Φ: an MLP 3 → width × depth → 1 with softplus activations."""

    def __new__(
        cls,
        *,
        width: int = 32,
        depth: int = 3,
        beta: float = 100.0,
        init_radius: float = 0.3,
        learned_init: bool = False,
    ) -> MlpSettings: ...
    @property
    def width(self) -> int: ...
    @property
    def depth(self) -> int: ...
    @property
    def beta(self) -> float: ...
    @property
    def init_radius(self) -> float: ...
    @property
    def learned_init(self) -> bool: ...

@final
class FitSettings:
    """The self-supervised fit of Φ to the target (Adam; lengths normalised)."""

    def __new__(
        cls,
        *,
        prefit_steps: int = 250,
        model_prefit_steps: int = 2000,
        prefit_lr: float = 0.002,
        refine_steps: int = 10,
        refine_lr: float = 0.001,
        batch_queries: int = 256,
        refine_batch_queries: int = 128,
        batch_source: int = 128,
        batch_surface: int = 128,
        query_pool: int = 16384,
        sigma_neighbour: int = 50,
        sigma_sample: int = 1024,
        lambda_surface: float = 0.1,
        lambda_eikonal: float = 0.001,
        max_source_queries: int = 16384,
        local: Optional[LocalSettings] = None,
    ) -> FitSettings: ...
    @property
    def prefit_steps(self) -> int: ...
    @property
    def model_prefit_steps(self) -> int: ...
    @property
    def prefit_lr(self) -> float: ...
    @property
    def refine_steps(self) -> int: ...
    @property
    def refine_lr(self) -> float: ...
    @property
    def batch_queries(self) -> int: ...
    @property
    def refine_batch_queries(self) -> int: ...
    @property
    def batch_source(self) -> int: ...
    @property
    def batch_surface(self) -> int: ...
    @property
    def query_pool(self) -> int: ...
    @property
    def sigma_neighbour(self) -> int: ...
    @property
    def sigma_sample(self) -> int: ...
    @property
    def lambda_surface(self) -> float: ...
    @property
    def lambda_eikonal(self) -> float: ...
    @property
    def max_source_queries(self) -> int: ...
    @property
    def local(self) -> LocalSettings: ...

@final
class LocalSettings:
    """The local part of Φ (scenes): a sparse voxel grid of corrections near the target's
    points, added to the MLP (lengths normalised: the target's largest side is 1)."""

    def __new__(
        cls,
        *,
        kind: str = "auto",
        auto_ratio: float = 400.0,
        cells: int = 128,
        voxel: Optional[float] = None,
        voxel_size: Optional[float] = None,
        spacings: float = 3.0,
        band: int = 1,
        batch: int = 2048,
        pool: int = 65536,
        sigma_voxels: float = 0.5,
        lr_scale: float = 1.0,
        plane_fit: bool = True,
        prefit_steps: int = 200,
        refine_steps: int = 40,
        network_batch_divisor: int = 1,
        min_voxel_spacings: float = 0.5,
        max_memory_mib: float = 1024.0,
        global_rerun_below_fitness: float = 0.35,
    ) -> LocalSettings: ...
    @property
    def kind(self) -> str: ...
    @property
    def auto_ratio(self) -> float: ...
    @property
    def cells(self) -> int: ...
    @property
    def voxel(self) -> Optional[float]: ...
    @property
    def voxel_size(self) -> Optional[float]: ...
    @property
    def spacings(self) -> float: ...
    @property
    def band(self) -> int: ...
    @property
    def batch(self) -> int: ...
    @property
    def pool(self) -> int: ...
    @property
    def sigma_voxels(self) -> float: ...
    @property
    def lr_scale(self) -> float: ...
    @property
    def plane_fit(self) -> bool: ...
    @property
    def prefit_steps(self) -> int: ...
    @property
    def refine_steps(self) -> int: ...
    @property
    def network_batch_divisor(self) -> int: ...
    @property
    def min_voxel_spacings(self) -> float: ...
    @property
    def max_memory_mib(self) -> float: ...
    @property
    def global_rerun_below_fitness(self) -> float: ...

@final
class MultistartSettings:
    """The multi-start: initial hypotheses when no ``init`` is given (lengths normalised)."""

    def __new__(
        cls,
        *,
        enabled: bool = True,
        offset: float = 0.1,
        points: int = 128,
        lm_steps: int = 5,
        keep: int = 4,
        refine_steps: int = 15,
        truncation: float = 0.05,
        tie: float = 0.25,
        distinct_rotation_deg: float = 5.0,
        distinct_translation: float = 0.02,
        hypotheses: int = 3,
        rescue: bool = True,
        grid_cells: int = 32,
        scene_turn_deg: float = 30.0,
        scene_as_given: bool = True,
    ) -> MultistartSettings: ...
    @property
    def enabled(self) -> bool: ...
    @property
    def offset(self) -> float: ...
    @property
    def points(self) -> int: ...
    @property
    def lm_steps(self) -> int: ...
    @property
    def keep(self) -> int: ...
    @property
    def refine_steps(self) -> int: ...
    @property
    def truncation(self) -> float: ...
    @property
    def tie(self) -> float: ...
    @property
    def distinct_rotation_deg(self) -> float: ...
    @property
    def distinct_translation(self) -> float: ...
    @property
    def hypotheses(self) -> int: ...
    @property
    def rescue(self) -> bool: ...
    @property
    def grid_cells(self) -> int: ...
    @property
    def scene_turn_deg(self) -> float: ...
    @property
    def scene_as_given(self) -> bool: ...

@final
class CoarseToFineSettings:
    """The coarse-to-fine schedule (paper eq. 18-1) and the final LM on the frozen Φ."""

    def __new__(
        cls,
        *,
        alternations: int = 10,
        scene_alternations: int = 5,
        lm_steps_per_alternation: int = 2,
        final_lm_steps: int = 10,
        scene_lm_steps_per_alternation: int = 5,
        scene_final_lm_steps: int = 30,
        final_lm_baked: bool = False,
    ) -> CoarseToFineSettings: ...
    @property
    def alternations(self) -> int: ...
    @property
    def scene_alternations(self) -> int: ...
    @property
    def lm_steps_per_alternation(self) -> int: ...
    @property
    def final_lm_steps(self) -> int: ...
    @property
    def scene_lm_steps_per_alternation(self) -> int: ...
    @property
    def scene_final_lm_steps(self) -> int: ...
    @property
    def final_lm_baked(self) -> bool: ...

@final
class LmSettings:
    """The Levenberg–Marquardt solver on SE(3)."""

    def __new__(
        cls,
        *,
        initial_lambda: float = 0.01,
        lambda_decrease: float = 3.0,
        lambda_increase: float = 4.0,
        max_tries: int = 6,
        rotation_tolerance: float = 1e-5,
        translation_tolerance: float = 1e-5,
    ) -> LmSettings: ...
    @property
    def initial_lambda(self) -> float: ...
    @property
    def lambda_decrease(self) -> float: ...
    @property
    def lambda_increase(self) -> float: ...
    @property
    def max_tries(self) -> int: ...
    @property
    def rotation_tolerance(self) -> float: ...
    @property
    def translation_tolerance(self) -> float: ...

@final
class RobustSettings:
    """The robust (Geman–McClure) kernel and when it is used."""

    def __new__(
        cls,
        *,
        mode: str = "auto",
        below_fitness: float = 0.35,
        outside_share: float = 0.2,
        gain: float = 1.3,
        rerun_tie: float = 0.05,
        scale: Optional[float] = None,
        kappa_start: float = 3.0,
        kappa_end: float = 1.0,
        floor: float = 0.002,
    ) -> RobustSettings: ...
    @property
    def mode(self) -> str:
        """``"auto"``, ``"on"``, ``"off"`` or ``"fixed"``."""
    @property
    def below_fitness(self) -> float: ...
    @property
    def outside_share(self) -> float: ...
    @property
    def gain(self) -> float: ...
    @property
    def rerun_tie(self) -> float: ...
    @property
    def scale(self) -> Optional[float]: ...
    @property
    def kappa_start(self) -> float: ...
    @property
    def kappa_end(self) -> float: ...
    @property
    def floor(self) -> float: ...

@final
class PolishSettings:
    """The final point-to-plane polish against the target points (lengths normalised)."""

    def __new__(
        cls,
        *,
        iterations: int = 50,
        neighbours: int = 5,
        scene_neighbours: int = 15,
        max_distance: float = 0.05,
        max_shift: float = 0.05,
        near_spacings: float = 3.0,
        prior_weight: float = 1e-4,
        scene_prior_weight: float = 1e-6,
        tolerance: float = 1e-7,
        snap: bool = True,
        target_planes: bool = False,
        patience: int = 0,
        scene_tolerance_spacings: float = 0.1,
        scene_kernel_floor_spacings: float = 1.0,
        kernel_floor_spacings: float = 0.25,
        scene_points: int = 0,
        scene_iterations: int = 50,
    ) -> PolishSettings: ...
    @property
    def iterations(self) -> int: ...
    @property
    def neighbours(self) -> int: ...
    @property
    def scene_neighbours(self) -> int: ...
    @property
    def max_distance(self) -> float: ...
    @property
    def max_shift(self) -> float: ...
    @property
    def near_spacings(self) -> float: ...
    @property
    def prior_weight(self) -> float: ...
    @property
    def scene_prior_weight(self) -> float: ...
    @property
    def tolerance(self) -> float: ...
    @property
    def snap(self) -> bool: ...
    @property
    def target_planes(self) -> bool: ...
    @property
    def patience(self) -> int: ...
    @property
    def scene_tolerance_spacings(self) -> float: ...
    @property
    def scene_kernel_floor_spacings(self) -> float: ...
    @property
    def kernel_floor_spacings(self) -> float: ...
    @property
    def scene_points(self) -> int: ...
    @property
    def scene_iterations(self) -> int: ...

@final
class ShiftSearchSettings:
    """The search for translations that lay more source points onto the target (normalised)."""

    def __new__(
        cls,
        *,
        radius: float = 0.3,
        voxel: float = 0.02,
        candidates: int = 4,
        min_gain: float = 0.02,
        scene_voxel_spacings: float = 3.0,
        scene_min_gain: float = 0.005,
    ) -> ShiftSearchSettings: ...
    @property
    def radius(self) -> float: ...
    @property
    def voxel(self) -> float: ...
    @property
    def candidates(self) -> int: ...
    @property
    def min_gain(self) -> float: ...
    @property
    def scene_voxel_spacings(self) -> float: ...
    @property
    def scene_min_gain(self) -> float: ...

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
        ``p_target = R @ p_source + t``, in the clouds' units; with ``scale=True`` the
        similarity ``[s R t; 0 1]``, ``p_target = s R @ p_source + t``."""
    @property
    def scale(self) -> float:
        """The scale ``s`` of the similarity (target units per source unit); 1.0 when rigid."""
    @property
    def similarity_information(self) -> Optional[npt.NDArray[np.float64]]:
        """With ``scale=True``: the 7×7 JᵀJ of the step [rotation (rad); translation (units);
        log-scale], about the target origin; None when rigid."""
    @property
    def scale_relative_eigenvalue(self) -> Optional[float]:
        """With ``scale=True``: how well the clouds fix the scale once every rigid motion is
        free to compensate (relative to the largest constraint eigenvalue); None when rigid."""
    @property
    def scale_free(self) -> bool:
        """With ``scale=True``: whether the clouds leave the scale free (a flat overlap looks the
        same at every size); the scale is then arbitrary. False when rigid."""
    @property
    def converged(self) -> bool:
        """Whether the stage that set the final pose converged (the polish's last pass when it
        was applied, else the final Levenberg–Marquardt steps); see ``stop_reason``."""
    @property
    def stop_reason(self) -> str:
        """Why that stage stopped: ``"small_step"``, ``"no_decrease"``, ``"max_iterations"`` or (the
        polish) ``"stalled"``."""
    @property
    def fitness(self) -> float:
        """Fraction of source points within ``inlier_distance`` of a target point."""
    @property
    def robust(self) -> bool:
        """Whether the robust kernel produced this result (``robust="on"``, or least squares
        fitted poorly and the robust re-run fitted better; ``stages["robust"]`` says which)."""
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
    def stages(self) -> Dict[str, Any]:
        """What each stage did: ``initial`` (``given``, ``starts``, ``hypotheses``,
        ``rotation_deg``), ``coarse_to_fine`` (``survivors``, ``winner``), ``final_lm``
        (``stop_reason``), ``robust`` (``kind``: ``"off"``, ``"from_start"``, ``"not_needed"``,
        ``"rerun_kept"`` or ``"rerun_rejected"``, with the fitnesses), ``polish`` (``result``:
        ``"off"``, ``"applied"``, ``"snapped"`` or ``"undone"``; ``iterations``,
        ``stop_reason``), ``shift_search`` (``peaks``, ``taken``, ``fitness_gain``) and
        ``rescue`` (``kind``: ``"not_tried"``, ``"kept"`` or ``"rejected"``, with both results'
        outside shares and fitnesses), ``global_rerun`` (a scene's full call run again with a
        global Φ: ``kind`` ``"not_tried"``, ``"kept"`` or ``"rejected"``, with both
        fitnesses). Each stage that
        can move the pose has a ``change``: ``rotation_deg`` and ``translation`` (RMS
        displacement of the source points, the clouds' units). ``swapped``: True when the
        target was registered onto the source and the result inverted (``swap_ratio``); the
        stages are then that run's."""
    @property
    def time_s(self) -> float:
        """Wall time of the registration, seconds."""
    @property
    def stage_times_s(self) -> Dict[str, float]:
        """Wall time of each stage, seconds, in pipeline order: ``prefit`` (fitting Φ on the
        target; 0 against a model), ``initial``, ``coarse_to_fine``, ``final_lm``, ``polish``,
        ``shift_search``, ``measure`` and ``other_run`` (the robust re-run's run that was not
        returned; 0 when none ran)."""
    @property
    def points_left_out(self) -> Dict[str, Dict[str, int]]:
        """The points left out of each cloud before registering, as a dict: ``{"source":
        {"missing_returns": n, "stray": m}, "target": {...}}`` (points at exactly (0, 0, 0), two
        or more; stray points far off the rest). The target's are 0 against a model (its fit
        left them out)."""
    def __reduce__(self) -> Any: ...


# The settings keywords, each declared once (the binding's table `KEYWORDS` in
# crates/sdfreg-py/src/settings.rs lists the same names per function; tests/test_stubs.py holds
# the two equal). None, or leaving a keyword out, keeps the preset's value; the functions'
# docstrings say what each one means.
class _SeedKeyword(TypedDict, total=False):
    seed: int

class _ThreadsKeyword(TypedDict, total=False):
    threads: int

class _SourceKeywords(TypedDict, total=False):
    max_source_points: Optional[int]
    lm: Optional[LmSettings]
    polish: Optional[PolishSettings]

class _TargetKeywords(TypedDict, total=False):
    max_target_points: Optional[int]
    mlp: Optional[MlpSettings]
    fit: Optional[FitSettings]
    model: Optional[str]

class _PipelineKeywords(TypedDict, total=False):
    preset: Optional[str]
    robust: Union[str, RobustSettings, None]
    inlier_distance: Optional[float]
    free_motion_ratio: Optional[float]
    multistart: Optional[MultistartSettings]
    coarse_to_fine: Optional[CoarseToFineSettings]
    shift_search: Optional[ShiftSearchSettings]

class _ScaleKeywords(TypedDict, total=False):
    scale: Optional[bool]
    scale_range: Optional[Tuple[float, float]]

class _FullCallKeywords(TypedDict, total=False):
    swap_ratio: Optional[float]

class _AlignKeywords(_SeedKeyword, _ThreadsKeyword, _SourceKeywords, _TargetKeywords, _PipelineKeywords, total=False):
    """``align``'s settings of its pairwise registrations."""

class _ManyKeywords(_SeedKeyword, _SourceKeywords, _TargetKeywords, _PipelineKeywords, _ScaleKeywords, _FullCallKeywords, total=False):
    """``register_many``'s settings (its ``threads`` is an argument of its own)."""

class _RegisterKeywords(_ManyKeywords, _ThreadsKeyword, total=False):
    """``register``'s and ``SdfModel.register``'s settings."""

class _MeshKeywords(_SeedKeyword, _ThreadsKeyword, _SourceKeywords, _PipelineKeywords, _ScaleKeywords, total=False):
    """``MeshModel.register``'s settings (nothing is fitted to a mesh)."""

class _TrackKeywords(_SeedKeyword, _ThreadsKeyword, _SourceKeywords, total=False):
    """``SdfModel.track``'s settings, over the ``"tracking"`` preset."""

class _FitKeywords(_SeedKeyword, _ThreadsKeyword, _TargetKeywords, total=False):
    """``fit``'s settings."""

def _settings_keywords() -> Dict[str, List[str]]:
    """Each settings keyword of the binding and the functions that take it (for the tests)."""

def register(
    source: Union[npt.ArrayLike, _HasPoints],
    target: Union[npt.ArrayLike, _HasPoints, SdfModel, MeshModel],
    *,
    init: Optional[npt.ArrayLike] = None,
    refine: Optional[bool] = None,
    **settings: Unpack[_RegisterKeywords],
) -> Registration:
    """Registers ``source`` onto ``target``: finds the rigid transform that moves the source
    cloud onto the target's surface, without point correspondences.

    The target is represented by a small neural signed distance function Φ, fitted to it; the
    source is moved by Levenberg–Marquardt so that ``Σ Φ(R p + t)²`` is minimal, alternating
    with refinements of Φ near the moving source. Without ``init``, the centroids are aligned
    and the 24 rotations of the cube group (and small shifts) are tried, so any initial
    rotation works.

    Args:
        source: (N, 3) points to move: a float32 or float64 array in any memory layout, an
            Open3D ``PointCloud`` (anything with a ``.points`` that numpy reads), or anything
            ``numpy.asarray`` turns into one.
        target: (M, 3) points that stay fixed, same units as ``source``; or an
            :class:`SdfModel` of them (:func:`fit`), registered against without fitting; or a
            :class:`MeshModel` (:func:`mesh_model`), a mesh's exact distance field.
            Points at exactly (0, 0, 0) (two or more: a scanner's missing returns) and stray
            points (under 1 % of a cloud, more than 30 times as far from its middle as 99 % of
            it) are left out of either cloud.
        init: Optional 4×4 rigid initial guess mapping source into target; replaces the
            multi-start.
        refine: With an :class:`SdfModel` target: refine a private copy of Φ with the moved
            source among its queries, as registering against the cloud does (slower; the same
            numbers as the cloud). None: False for a model (Φ frozen); a cloud is always
            refined.
        preset: ``"default"``, ``"scans"`` for scans known to overlap only in part (the
            robust kernel from the start, multi-start tie 0.05), ``"views"`` (``"scans"`` with an
            object's polish pass ending when its steps stop shrinking, against planes at the target's points; a scene's polish on 16384 source points), or ``"learned"`` (an object's pre-fit of 150 steps from an initialisation learned on procedural objects: about 0.7 of the time). The arguments below override it; None keeps the
            preset's value.
        robust: ``"auto"`` (least squares, redone with the robust kernel when it fits poorly),
            ``"on"``, ``"off"``, or a :class:`RobustSettings`.
        seed: Seed of every random choice; equal seeds give identical results.
        threads: Worker threads; 0 = one per core. The result does not depend on it.
        max_source_points: Source points used at most (larger clouds are subsampled, seeded).
        max_target_points: Target points used at most.
        inlier_distance: A source point within this distance of a target point is an inlier
            (``fitness``, ``inlier_rmse``); a fraction of the target's largest side.
        free_motion_ratio: Constraint eigenvalues below this (relative) are reported as
            ``free_motions``.
        mlp: The SDF network (:class:`MlpSettings`).
        fit: Fitting Φ (:class:`FitSettings`).
        multistart: The initial hypotheses (:class:`MultistartSettings`).
        coarse_to_fine: The alternation schedule (:class:`CoarseToFineSettings`).
        lm: The Levenberg–Marquardt solver (:class:`LmSettings`).
        polish: The final point-to-plane steps (:class:`PolishSettings`).
        shift_search: The translation search (:class:`ShiftSearchSettings`).
        scale: Estimate a scale with the pose (similarity registration: millimetres against
            metres, an SfM reconstruction against a LiDAR map). ``transformation`` is then
            ``[s R | t]`` and :attr:`Registration.scale` holds ``s``; with ``init``, the scale
            of its 3×3 block is the start. Default False (rigid).
        scale_range: ``(min, max)``: the scale (target units per source unit) stays within
            them; needs ``scale=True``. Default 0.1 to 10 times the unit factor (1, 1000 or
            0.001) the clouds' extents point to.
        swap_ratio: A cloud target with at least this many times fewer points than the source
            (and at least half its size) is registered the other way round, the denser cloud as
            Φ's, and the result inverted (``stages["swapped"]``); 0 never. Default 4.
        model: Kind of Φ fitted to a cloud target: ``"global"`` (one MLP: objects),
            ``"local"`` (the MLP plus a sparse voxel grid of corrections near the target's
            points: rooms, streets), or ``"auto"`` (local when the target's largest side is at
            least 400 point spacings). None keeps ``fit``'s (auto by default).

    A settings object replaces the preset's whole group.

    Returns:
        The :class:`Registration`.

    Raises:
        ValueError: a cloud is not an (N, 3) float array, has a NaN or infinite coordinate,
            fewer than 10 points or no extent; ``init`` is not a rigid 4×4 transform (with
            ``scale=True``: not a positive scale times a rotation); a setting is out of range
            (``scale_range`` with min ≥ max or a bound ≤ 0).

    Warns:
        UserWarning: the target is a local (scene) :class:`SdfModel` and the result fits less
            than ``LocalSettings.global_rerun_below_fitness`` of the source (a full call would
            run again with a global Φ): scans that overlap only in part register more reliably
            against a model fitted with ``model="global"``.
        UserWarning: points were left out of ``source`` or a cloud ``target``: missing returns
            at (0, 0, 0) or stray points, one warning per kind and cloud with how many
            (:attr:`Registration.points_left_out` holds the counts).
    """

def align(
    scans: Iterable[npt.ArrayLike],
    *,
    init: Optional[Iterable[Optional[npt.ArrayLike]]] = None,
    anchor: int = 0,
    closure_pairs: int = 2,
    joint_rounds: int = 0,
    consensus_iterations: int = 0,
    seen_from: Union[str, Sequence[float], None] = None,
    max_in_free_space: float = 0.02,
    **settings: Unpack[_AlignKeywords],
) -> Alignment:
    """Aligns many scans (views of one object or scene) into the frame of one of them.

    Each scan gets a stored model; the pairs are registered through them (all pairs up to 16
    scans, else each scan with its next 3 in order, wrapping round, then at most
    ``closure_pairs`` more per scan between placed scans that overlap far apart along the
    graph); the registrations that fit (fitness ≥ 0.3), that a cycle through a third scan
    confirms and that agree with a spanning tree (groups of scans joined where most of the
    fitness of the edges between them agrees) form a pose graph, solved
    by robust Gauss–Newton on SE(3); then each scan is registered against one model of all
    the others (``joint_rounds`` times, none by default). No initial guesses are needed.

    Args:
        scans: A sequence of (N, 3) point arrays, each in its own frame, the same units.
        init: Approximate poses, one 4×4 per scan (scan into the anchor's frame: a turntable's
            angles, odometry; None for a scan without one, whose pairs then start from nothing,
            as :func:`read_poses` gives a scan left out), or None.
        anchor: The scan whose frame the poses map into.
        closure_pairs: Above 16 scans, the pairs each scan joins once the graph has placed
            them, between scans that overlap and lie at least 5 kept edges apart (loop
            closures); 0 skips. Default 2.
        joint_rounds: Joint refinement rounds (each scan against one model of the others);
            0 skips.
        consensus_iterations: Iterations of the multi-view point-to-plane refinement after the
            pose graph (every pose at once, against the other scans' points); 0 (the default)
            skips it.
        seen_from: Where each scan was seen from, in its own frame: ``"origin"`` (a LiDAR or
            depth camera's scan in its sensor's frame), an axis such as ``"+z"`` (a scanner far
            along +z, as the Stanford scans) or a direction ``(x, y, z)``. A pair that puts more
            than ``max_in_free_space`` of either scan where the other's sensor saw empty space is
            then no edge. None (the default): no such check.
        max_in_free_space: See ``seen_from``; a share of the scan's points. Default 0.02.
        seed: Seed of every random choice.
        threads: Worker threads; 0 = one per core.
        preset: The pairs' preset, ``"views"`` by default (``"scans"``, the robust kernel from
            the start, with an object's polish pass ending when its steps stop shrinking, against planes at the target's points; a scene's polish on 16384 source points).

    The other keywords are :func:`register`'s (without ``scale``) and apply to every pair.

    Returns:
        The :class:`Alignment`.

    Raises:
        ValueError: fewer than two scans can be used, a scan is not an (N, 3) float array, the
            anchor names no scan, ``init`` has not one rigid 4×4 per scan, or a setting is out
            of range.

    Warns:
        UserWarning: points were left out of a scan: missing returns at (0, 0, 0) or stray
            points, one warning per kind and scan (``scans[k]``) with how many.
    """

@final
class Alignment:
    """The outcome of :func:`align`. Read-only."""

    @property
    def poses(self) -> List[Optional[npt.NDArray[np.float64]]]:
        """Per scan, the 4×4 mapping its coordinates into the anchor's frame; None for a scan left
        out."""
    @property
    def left_out(self) -> List[Tuple[int, str]]:
        """The scans left out, as ``(index, why)``."""
    @property
    def anchor(self) -> int:
        """The index of the anchor scan."""
    @property
    def fitness(self) -> List[float]:
        """Per scan, the best fitness of a kept pairwise registration it is part of."""
    @property
    def edges(self) -> List[Dict[str, Any]]:
        """Every pairwise registration, as dicts: ``target``, ``source`` (scan indices; the
        source was moved onto the target), ``fitness``, ``kept`` (used by the pose graph),
        ``in_free_space`` (with ``seen_from``: the larger share of either scan that it puts in
        the other's free space; else None), and ``registration`` (a :class:`Registration`) or
        ``error``."""
    @property
    def model(self) -> SdfModel:
        """One model of all the placed scans in the anchor's frame (mesh it with
        ``model.mesh()``, save it with ``model.save(path)``)."""
    @property
    def time_s(self) -> float:
        """Wall time, seconds."""
    @property
    def consensus(self) -> Dict[str, Any]:
        """What the multi-view refinement (``consensus_iterations``) did: ``pairs`` (ordered pairs
        of scans measured), ``iterations``, ``mean_residual_before`` and ``mean_residual_after``
        (mean distance of the measured points to the other scans' planes, scan units),
        ``undone`` (the graph's poses kept: the residual did not fall). Zeros when it did not run.
        """
    @property
    def stage_times_s(self) -> Dict[str, float]:
        """Each stage's wall time, seconds: ``models``, ``pairs``, ``graph``, ``unplaced``,
        ``consensus``, ``joint``."""
    def evaluate(
        self, scans: Iterable[npt.ArrayLike], max_distance: float
    ) -> List[Optional[Evaluation]]:
        """How well each placed scan lies on the others once aligned, with no reference: per scan,
        :func:`evaluate_registration` of the scan, moved by its pose, against all the other
        placed scans in the anchor's frame (those whose bounding boxes come within
        ``max_distance``), with missing returns and stray points left out of each. The
        distances are measured in one frame for all the scans, so a figure may differ from
        :func:`evaluate_registration`'s in the last digits; each point costs about log2(n)
        k-d tree look-ups for n scans.

        A scan's parts that no other scan saw count against its fitness: compare the figures
        with those of other poses of the same scans (a reference's, another tool's), not with 1.

        Args:
            scans: The scans given to :func:`align`, in the same order.
            max_distance: A point is an inlier when another scan's point lies within this
                distance, in the scans' units.

        Returns:
            Per scan, an :class:`Evaluation`, or None for a scan left out.

        Raises:
            ValueError: ``scans`` are not as many as the alignment's, or one is not an (N, 3)
                float array; ``max_distance`` is not positive and finite.
        """
    def to_json(self, files: Optional[List[str]] = None) -> str:
        """The poses file of this alignment, as ``sdfreg align --output poses.json`` writes it
        (``format`` ``"sdfreg-poses"``; per scan ``file``, ``transformation`` or null,
        ``fitness``; ``edges``; the times): write it to a file, read it back with
        :func:`read_poses`.

        Args:
            files: A name per scan, in order (default ``"scan 0"``, ``"scan 1"``, …).

        Raises:
            ValueError: ``files`` does not name every scan once.
        """

def read_poses(path: _PathLike) -> List[Optional[npt.NDArray[np.float64]]]:
    """Reads the poses of a poses file (``sdfreg align --output poses.json``,
    :meth:`Alignment.to_json`): per scan, in order, its 4×4 (scan into the anchor's frame), None
    for a scan left out. The list passes as ``align(scans, init=...)``.

    Raises:
        OSError: the file cannot be read (``FileNotFoundError``, …), is not JSON (the message
            names the line), is another program's or another sdfreg file, of a newer version,
            or holds a transformation that is not a rigid 4×4 (the message names the scan).
    """

def register_many(
    pairs: Iterable[
        Union[
            Tuple[
                Union[npt.ArrayLike, _HasPoints],
                Union[npt.ArrayLike, _HasPoints, SdfModel, MeshModel],
            ],
            Tuple[
                Union[npt.ArrayLike, _HasPoints],
                Union[npt.ArrayLike, _HasPoints, SdfModel, MeshModel],
                Optional[npt.ArrayLike],
            ],
        ]
    ],
    *,
    threads: int = 0,
    progress: Union[bool, Callable[[int, int], object]] = False,
    **settings: Unpack[_ManyKeywords],
) -> List[Union[Registration, Exception]]:
    """Registers many pairs at once, on every core: one pair per worker thread, each
    registration single-threaded, the GIL released while they run.

    Args:
        pairs: An iterable of ``(source, target)`` or ``(source, target, init)``: clouds as
            :func:`register` takes them, a target cloud or an :class:`SdfModel` (registered
            against with Φ frozen; one model may serve many pairs), ``init`` a 4×4 or None.
        threads: Pairs registered at once; 0 = one per core.
        progress: True for a progress bar on stderr (tqdm's when it is installed), or a
            callable ``progress(done, total)`` called after each pair, from this thread.
        **settings: The settings keywords of :func:`register` (``preset``, ``robust``,
            ``seed``, ``max_source_points``, …, the settings groups), the same for every pair.

    Returns:
        A list in the order of ``pairs``: each pair's :class:`Registration`, bit-identical to
        ``register(source, target, init=init, **settings)``; or, for a pair that failed, the
        exception ``register`` would have raised (``ValueError``), its message starting with
        ``pair i:``. The others are not affected.

    Raises:
        ValueError: a setting is out of range (before any pair runs).
        TypeError: ``pairs`` is not iterable, or a keyword names no setting.
        KeyboardInterrupt: Ctrl-C; the pairs already running finish first (at most one per
            worker).
    """

@final
class SdfModel:
    """A target fitted once (see :func:`fit`). Immutable; pickles (through its ``.sdfm``
    bytes) to multiprocessing, Dask and Ray workers."""

    def register(
        self,
        source: Union[npt.ArrayLike, _HasPoints],
        *,
        init: Optional[npt.ArrayLike] = None,
        refine: Optional[bool] = None,
        **settings: Unpack[_RegisterKeywords],
    ) -> Registration:
        """Registers ``source`` onto this model: ``sdfreg.register(source, model, **kwargs)``
        (Φ frozen unless ``refine=True``)."""
    def distance(self, points: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """Signed distance Φ at ``points`` ((N, 3), the target's units and frame), positive
        outside, as an (N,) float64 array."""
    def gradient(self, points: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """∇Φ at ``points`` as an (N, 3) float64 array (about unit length near the surface)."""
    def closest_points(self, points: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """The closest surface point of each of ``points``, ``p − Φ ∇Φ/‖∇Φ‖``, as (N, 3)."""
    def mesh(
        self, resolution: int = 128
    ) -> Tuple[npt.NDArray[np.float64], npt.NDArray[np.int64]]:
        """Φ's zero level set as a triangle mesh: ``(vertices (V, 3) float64, faces (F, 3)
        int64)``, the target's units and frame, outward normals by the right-hand rule.
        ``resolution``: grid cells along the target's largest side (4 to 1024)."""
    def track(
        self,
        frames: Iterable[Union[npt.ArrayLike, _HasPoints]],
        *,
        init: Optional[npt.ArrayLike] = None,
        **settings: Unpack[_TrackKeywords],
    ) -> List[Union[Registration, ValueError]]:
        """Registers a sequence of ``frames`` ((N, 3) each) against the model, the first from
        ``init`` (4×4, frame into target; identity when None), each next one from the previous
        frame's pose, with the ``"tracking"`` preset (no multi-start, a few LM steps, a short
        polish) and these overrides. Returns one :class:`Registration` per frame, or the
        ``ValueError`` of a frame that could not be registered, in its place. Points left out
        of a frame are counted in its result's ``points_left_out``, without a warning."""
    @property
    def target_points(self) -> npt.NDArray[np.float64]:
        """The target points Φ was fitted to (subsampled), (M, 3), the target's units and frame."""
    @property
    def seed(self) -> int:
        """The seed the model was fitted with."""
    @property
    def kind(self) -> str:
        """``"global"`` (Φ is one MLP) or ``"local"`` (the MLP plus a sparse voxel grid of
        corrections near the target's points), as ``model=`` decided it."""
    @property
    def voxel(self) -> Optional[float]:
        """A local model's voxel side, in the target's units; None for a global model."""
    @property
    def local_parameters(self) -> int:
        """The local grid's corrections (one per voxel corner near the target); 0 for a global
        model."""
    def save(self, path: _PathLike) -> None:
        """Writes the model to ``path`` (``.sdfm``: a safetensors file, readable without sdfreg);
        an existing file is replaced.

        Raises:
            OSError: the file cannot be written.
        """
    def to_bytes(self) -> bytes:
        """The ``.sdfm`` file's bytes."""
    def __reduce__(self) -> Any: ...

def fit(
    target: Union[npt.ArrayLike, _HasPoints],
    **settings: Unpack[_FitKeywords],
) -> SdfModel:
    """Fits the SDF model of ``target`` once, to register many sources against it.

    Runs the first stages of :func:`register` on the target alone: the normalisation and the
    pre-fit of Φ. ``register(source, model)`` (or ``model.register(source)``) then skips them.

    Args:
        target: (M, 3) points (array, Open3D ``PointCloud``, …), any units.
        seed: Seed of every random choice; equal seeds give identical models.
        threads: Worker threads; 0 = one per core. The model does not depend on it.
        max_target_points: Target points used at most (larger clouds are subsampled, seeded).
        mlp: The network (:class:`MlpSettings`).
        fit: The fit (:class:`FitSettings`).
        model: Kind of Φ: ``"global"`` (one MLP: objects), ``"local"`` (the MLP plus a sparse
            voxel grid of corrections near the target's points: rooms, streets), or ``"auto"``
            (local when the target's largest side is at least 400 point spacings). None keeps
            ``fit``'s (auto by default).

    Returns:
        The :class:`SdfModel`.

    Raises:
        ValueError: ``target`` is not an (N, 3) float array, has a NaN or infinite coordinate,
            fewer than 10 points or no extent; a setting is out of range.

    Warns:
        UserWarning: points were left out of ``target``: missing returns at (0, 0, 0) or stray
            points, one warning per kind with how many.
    """

def load_model(path: _PathLike) -> SdfModel:
    """Reads a model written by :meth:`SdfModel.save` (``.sdfm``).

    Raises:
        OSError: the file cannot be read, or it is not an sdfreg model: truncated, corrupted
            (checksum), of another program, or of a newer format version; the message names
            the file and what is wrong.
    """

@final
class MeshModel:
    """A target mesh as its exact distance field (see :func:`mesh_model`). Immutable; pickles
    (through its vertices and faces)."""

    def register(
        self,
        source: Union[npt.ArrayLike, _HasPoints],
        *,
        init: Optional[npt.ArrayLike] = None,
        **settings: Unpack[_MeshKeywords],
    ) -> Registration:
        """Registers ``source`` onto the mesh: ``sdfreg.register(source, mesh, **kwargs)``."""
    def distance(self, points: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """The distance at ``points`` ((N, 3), the mesh's units and frame), negative inside when
        :attr:`is_signed`, as an (N,) float64 array."""
    def closest_points(self, points: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """The closest surface point of each of ``points``, as (N, 3)."""
    @property
    def is_signed(self) -> bool:
        """Whether the distance is signed: the mesh is closed and consistently wound."""
    @property
    def target_points(self) -> npt.NDArray[np.float64]:
        """The points sampled on the faces for the polish, (M, 3)."""
    def __reduce__(self) -> Any: ...

def mesh_model(
    vertices: npt.ArrayLike,
    faces: npt.ArrayLike,
    *,
    seed: int = 0,
    max_target_points: Optional[int] = None,
) -> MeshModel:
    """A target mesh as its own exact distance field: registering against it needs no fitting
    (scans onto CAD models or reconstructions).

    Φ(x) is the distance to the nearest triangle (signed, negative inside, when the mesh is
    closed and consistently wound; see :attr:`MeshModel.is_signed`); far from the surface
    (beyond four edge lengths from the nearest vertex) the nearest vertex's distance stands in.

    Args:
        vertices: (V, 3) points, any units.
        faces: (F, 3) integer vertex indices.
        seed: Seed of the target points sampled on the faces for the polish.
        max_target_points: How many target points are sampled (default: as ``register``).

    Raises:
        ValueError: ``vertices`` is not an (N, 3) finite float array, ``faces`` not an (F, 3)
            integer array, an index is out of range, there are no faces or they have no area.
    """

def read_mesh(path: _PathLike) -> Tuple[npt.NDArray[np.float64], npt.NDArray[np.int64]]:
    """Reads a PLY mesh: ``(vertices (V, 3) float64, faces (F, 3) int64)``; a cloud without faces
    gives an empty ``faces``.

    Raises:
        OSError: the file cannot be read, is not a PLY or is malformed (naming the file).
    """

def _mesh_model_from_parts(
    vertices: npt.ArrayLike, faces: npt.ArrayLike, seed: int, max_target_points: int
) -> MeshModel:
    """A MeshModel from its parts (unpickling)."""

def _model_from_bytes(data: bytes) -> SdfModel:
    """A model from ``.sdfm`` bytes (unpickling)."""

def evaluate_registration(
    source: Union[npt.ArrayLike, _HasPoints],
    target: Union[npt.ArrayLike, _HasPoints, SdfModel, MeshModel],
    max_distance: float,
    transformation: Optional[npt.ArrayLike] = None,
) -> Evaluation:
    """How well ``source``, moved by ``transformation``, lies on ``target``, at a distance in their
    units, with no registration run: as Open3D's ``evaluate_registration``.

    Use it to judge a result at your own tolerance (a :class:`Registration`'s ``fitness`` is at
    ``inlier_distance``, a fraction of the target's size), or to compare another tool's answer
    with sdfreg's on the same terms.

    Args:
        source: (N, 3) points to move (array, Open3D ``PointCloud``, …).
        target: (M, 3) points, fixed, the same units; or an :class:`SdfModel` (against the
            target points it was fitted to, :attr:`SdfModel.target_points`) or a
            :class:`MeshModel` (each source point's exact distance to the mesh's faces).
        max_distance: A source point is an inlier when its nearest target point lies within
            this distance, in the clouds' units (metres for a LiDAR scan).
        transformation: 4×4 mapping source into target (``Registration.transformation``, rigid
            or a similarity ``[s R | t]``); None: the identity, the clouds as they are.

    Missing returns at (0, 0, 0) and stray points are left out of both clouds first, as
    :func:`register` leaves them out (and warned the same way; a model's fit left out its
    target's); every other point counts.

    Returns:
        The :class:`Evaluation`: ``fitness``, ``inlier_rmse``, ``inliers``, ``source_points``.

    Raises:
        ValueError: a cloud is not an (N, 3) float array, has a NaN or infinite coordinate,
            fewer than 10 points or no extent; ``max_distance`` is not positive and finite;
            ``transformation`` is not a 4×4 similarity.
    """

@final
class Evaluation:
    """How well a transformed source lies on a target (see ``sdfreg.evaluate_registration``)."""

    @property
    def fitness(self) -> float:
        """Fraction of the source's points within ``max_distance`` of a target point."""
    @property
    def inlier_rmse(self) -> float:
        """RMS distance of those inliers to their nearest target points, the clouds' units; 0.0
        when there are none."""
    @property
    def inliers(self) -> int:
        """How many source points are inliers."""
    @property
    def source_points(self) -> int:
        """How many source points were counted (less the missing returns and stray points)."""
    @property
    def max_distance(self) -> float:
        """The distance asked for, the clouds' units."""
    @property
    def points_left_out(self) -> Dict[str, Dict[str, int]]:
        """The points left out of each cloud, as :attr:`Registration.points_left_out`."""
    def __reduce__(self) -> Any: ...

def _evaluation_from_json(json: str) -> Evaluation:
    """An evaluation from its JSON (unpickling)."""
def _registration_from_json(json: str) -> Registration:
    """A registration from its JSON (unpickling)."""

def _settings_from_json(name: str, json: str) -> Any:
    """A settings object of the class ``name`` from its JSON (unpickling)."""

def read_point_cloud(path: _PathLike, *, drop_non_finite: bool = False) -> npt.NDArray[np.float64]:
    """Reads a point cloud as an (N, 3) float64 array.

    Formats by extension: ``.ply`` (ascii or binary, any numeric type; the ``vertex``
    element's x, y, z), ``.pcd`` (ascii, binary or binary_compressed; the x, y, z fields),
    ``.las`` and ``.laz`` (any version and point format, LASzip-compressed or not; x, y, z
    with the file's scale and offset), ``.e57`` (every scan placed by its pose in the file's
    frame; spherical scans converted; points without coordinates skipped), ``.xyz``, ``.txt``,
    ``.csv``, ``.pts`` (first three columns; a ``.pts`` block's point-count line is
    checked against its rows).

    Args:
        path: The file.
        drop_non_finite: Drop points with a NaN or infinite coordinate (organised PCL clouds
            and range scanners mark missing returns that way) and warn how many, instead of
            raising.

    Raises:
        OSError: the file cannot be read (``FileNotFoundError``, ``PermissionError``, …), its
            format is unknown, or its contents are malformed; the message names the file and,
            for text and ascii PLY, the line.
    """

def read_e57_scans(
    path: _PathLike, *, drop_non_finite: bool = False
) -> List[Tuple[Optional[str], npt.NDArray[np.float64], npt.NDArray[np.float64]]]:
    """Reads each scan of an E57 file apart: a list of ``(name, pose, points)``, in the file's
    order. ``name`` is the scan's name in the file (``None`` if it has none), ``pose`` the
    (4, 4) float64 that maps the scan's coordinates into the file's frame, ``points`` its
    (N, 3) float64 points in its own frame (points the file marks as having no coordinates are
    not points; a scan may have none). :func:`read_point_cloud` gives all of them in the file's
    frame instead; ``sdfreg.align([points for _, _, points in scans])`` aligns them anew.

    Args:
        path: The ``.e57`` file.
        drop_non_finite: Drop points with a NaN or infinite coordinate and warn how many,
            instead of raising.

    Raises:
        OSError: the file cannot be read, is not an E57 file, fails a page's checksum, has no
            point in any scan, or a NaN coordinate (naming the file and the scan).
    """

def write_e57_scans(
    path: _PathLike,
    scans: Iterable[Tuple[Optional[str], npt.ArrayLike, npt.ArrayLike]],
) -> None:
    """Writes scans as the scans of one E57 file, each with its name, its pose and its points in
    its own frame as float64: what :func:`read_e57_scans` reads back, to the bit. An existing file
    is replaced. With :func:`align`, a campaign registered anew::

        scans = sdfreg.read_e57_scans("campaign.e57")
        aligned = sdfreg.align([points for _, _, points in scans])
        sdfreg.write_e57_scans("registered.e57", [
            (name, pose, points)
            for (name, _, points), pose in zip(scans, aligned.poses) if pose is not None
        ])

    Args:
        path: The ``.e57`` file to write.
        scans: ``(name, pose, points)`` per scan: ``name`` a str or ``None``, ``pose`` a (4, 4)
            rigid transform from the scan's frame into the file's, ``points`` (N, 3) finite.

    Raises:
        ValueError: a scan is not such a triple, its pose is not rigid or a point is not finite
            (naming the scan).
        OSError: the file cannot be written.
    """

def write_point_cloud(path: _PathLike, points: npt.ArrayLike) -> None:
    """Writes (N, 3) finite points; the format follows the extension (``.ply``: binary
    float64; ``.pcd``: binary float64; ``.las``: LAS 1.2 point format 0, integers at a
    scale of 10⁻⁹–10⁻⁸ of the cloud's extent, LASzip-compressed in ``.laz``; ``.e57``: one scan of float64; text formats: one ``x y z`` line per point, full
    precision, after a point-count line in ``.pts``). An existing file is replaced.

    Raises:
        ValueError: ``points`` is not an (N, 3) float array or has a non-finite coordinate.
        OSError: the file cannot be written or the extension is unknown.
    """

def write_moved_point_cloud(
    input: _PathLike, output: _PathLike, transformation: npt.ArrayLike
) -> Dict[str, Any]:
    """Writes the cloud file ``input`` moved by ``transformation`` (a 4×4 ``[s R | t]`` mapping
    its coordinates into the output's, such as a registration's, source into target) to
    ``output``. When ``output`` has ``input``'s format, every point keeps its other fields
    (intensity, colour, classification, GPS time, extra columns), its normals turned, and the
    file its other elements and header records: PLY and PCD (ascii or binary), LAS and LAZ, and
    text. Otherwise, or for a PCD ``binary_compressed`` body, integer or list coordinates in a
    PLY, or E57, the moved coordinates alone are written, as ``write_point_cloud`` does.
    Missing returns at (0, 0, 0) and non-finite points stay as they are. An existing file is
    replaced.

    Returns:
        A dict: ``points`` (written, in the input's order), ``left_in_place`` (missing returns
        and non-finite points), ``fields_kept`` (bool) and ``reason`` (why only the coordinates
        were written, else ``None``).

    Raises:
        ValueError: ``transformation`` is not a 4×4 similarity.
        OSError: ``input`` cannot be read or is not a valid cloud, or ``output`` cannot be
            written, or an extension is unknown.
    """

def _core_defaults() -> Dict[str, Any]:
    """The core's defaults of every settings group, as nested dicts (for tests)."""
