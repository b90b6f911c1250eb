"""Geometry that the generator and the reconstruction methods legitimately share, with a public API.

- :mod:`.tubes`: generalised-cylinder meshing of a skeleton (node frames, main-child choice, pipe-model radii);
- :mod:`.leaf`: the Bezier leaf of Chaurasia and Beardsley as a shape family (21 parameters), its surface,
  outline and tessellation;
- :mod:`.vectors`: unit vectors, perpendiculars, rotations, the Umeyama similarity and a tree's nodes by depth;
- :mod:`.perception`: the perception cones of space colonisation (markers to buds, Palubicki et al. 2009), shared by
  the generator's growth and Guo et al.'s reconstruction;
- :mod:`.clouds`: the observed height of a point cloud.

Growth loops, leaf placement and species loading stay in :mod:`plantbench.generate`, which no method imports.
"""
