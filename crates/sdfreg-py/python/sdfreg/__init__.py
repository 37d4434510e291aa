"""Correspondence-free rigid point-cloud registration by a neural signed distance function.

``register(source, target)`` moves ``source`` onto ``target`` and returns a
:class:`Registration` whose ``transformation`` (4×4) maps source coordinates into the target
frame. Clouds are (N, 3) arrays of float32 or float64 in any units, or Open3D point clouds.
Tuning goes in settings objects, one per stage: ``register(s, t, lm=LmSettings(max_tries=10))``;
``preset="scans"`` suits scans that overlap only in part.
"""

from ._sdfreg import (
    CoarseToFineSettings,
    FitSettings,
    FreeMotion,
    LmSettings,
    MlpSettings,
    MultistartSettings,
    PolishSettings,
    Registration,
    RobustSettings,
    ShiftSearchSettings,
    __version__,
    read_point_cloud,
    register,
    write_point_cloud,
)

__all__ = [
    "CoarseToFineSettings",
    "FitSettings",
    "FreeMotion",
    "LmSettings",
    "MlpSettings",
    "MultistartSettings",
    "PolishSettings",
    "Registration",
    "RobustSettings",
    "ShiftSearchSettings",
    "__version__",
    "read_point_cloud",
    "register",
    "write_point_cloud",
]
