"""Correspondence-free rigid point-cloud registration by a neural signed distance function.

``register(source, target)`` moves ``source`` onto ``target`` and returns a
:class:`Registration` whose ``transformation`` (4×4) maps source coordinates into the target
frame. Clouds are (N, 3) arrays of float32 or float64 in any units, or Open3D point clouds.
Tuning goes in settings objects, one per stage: ``register(s, t, lm=LmSettings(max_tries=10))``;
``preset="scans"`` suits scans that overlap only in part. ``fit(target)`` fits the target's
SDF once; ``register(source, model)`` then registers without fitting, and the model saves,
loads and pickles. ``register_many(pairs)`` registers many pairs on every core;
``sdfreg.dask`` spreads them over a Dask cluster. ``align(scans)`` puts many views into one
frame; ``Alignment.to_json()`` and ``read_poses(path)`` write and read its poses file.
``evaluate_registration(source, target, max_distance, transformation)`` gives a
transformation's fitness at a distance in the clouds' units.
"""

from ._sdfreg import (
    Alignment,
    CoarseToFineSettings,
    Evaluation,
    FitSettings,
    FreeMotion,
    LmSettings,
    LocalSettings,
    MeshModel,
    MlpSettings,
    MultistartSettings,
    PolishSettings,
    Registration,
    RobustSettings,
    SdfModel,
    ShiftSearchSettings,
    __version__,
    align,
    evaluate_registration,
    fit,
    load_model,
    mesh_model,
    read_e57_scans,
    write_e57_scans,
    read_mesh,
    read_point_cloud,
    read_poses,
    register,
    register_many,
    write_moved_point_cloud,
    write_point_cloud,
)

__all__ = [
    "Alignment",
    "CoarseToFineSettings",
    "Evaluation",
    "FitSettings",
    "FreeMotion",
    "LmSettings",
    "LocalSettings",
    "MeshModel",
    "MlpSettings",
    "MultistartSettings",
    "PolishSettings",
    "Registration",
    "RobustSettings",
    "SdfModel",
    "ShiftSearchSettings",
    "__version__",
    "align",
    "evaluate_registration",
    "fit",
    "load_model",
    "mesh_model",
    "read_e57_scans",
    "write_e57_scans",
    "read_mesh",
    "read_point_cloud",
    "read_poses",
    "register",
    "register_many",
    "write_moved_point_cloud",
    "write_point_cloud",
]
