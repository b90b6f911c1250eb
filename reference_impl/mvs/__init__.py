"""Multi-view point clouds on the CPU (Guo et al. 2018, section 4): dense depth maps, multi-view filtering, fusion.

The registered method is :class:`MVS` (``mvs``). The pieces are reusable: :func:`load_views`, :func:`depth_maps`
(raw per-view depth + normal maps), :func:`filter_depth_maps`, :func:`estimate_depth` (one reference view),
:func:`select_neighbours`, :func:`fuse_views` / :func:`voxel_downsample`, :func:`plant_mask`, :func:`run_sfm`.
Heavy backends (Dr.Jit, pycolmap, PIL) are imported inside the functions that use them.
"""

from .filtering import consistency_counts, guided_filter, masked_guided_filter
from .fusion import fuse_views, voxel_downsample
from .ground import fit_ground_plane, plant_mask
from .method import MVS, depth_maps, filter_depth_maps, load_views, reconstruct_points
from .neighbours import depth_range, scene_centre, select_neighbours
from .params import MVSParams
from .patchmatch import DepthMap, estimate_depth
from .sfm import run_sfm, umeyama

__all__ = [
    "MVS", "MVSParams", "DepthMap", "load_views", "depth_maps", "filter_depth_maps", "reconstruct_points",
    "estimate_depth", "select_neighbours", "scene_centre", "depth_range", "consistency_counts", "guided_filter",
    "masked_guided_filter", "fuse_views", "voxel_downsample", "fit_ground_plane", "plant_mask", "run_sfm", "umeyama",
]
