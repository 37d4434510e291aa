"""Correspondence-free rigid point-cloud registration by a neural signed distance function.

``register(source, target)`` moves ``source`` onto ``target`` and returns a
:class:`Registration` whose ``transformation`` (4×4) maps source coordinates into the target
frame. Clouds are (N, 3) arrays of float32 or float64 in any units; Open3D clouds pass as
``np.asarray(pcd.points)``.
"""

from ._sdfreg import (
    FreeMotion,
    Registration,
    __version__,
    read_point_cloud,
    register,
    write_point_cloud,
)

__all__ = [
    "FreeMotion",
    "Registration",
    "__version__",
    "read_point_cloud",
    "register",
    "write_point_cloud",
]
