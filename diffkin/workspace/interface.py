"""What the packages built on workspace use beyond its public names (internal: not in API.md).

The CLI sizes a map's voxel grid before it samples (to say how large the map will be).
"""

from diffkin.workspace._sampling import voxel_grid

__all__ = ["voxel_grid"]
