"""Geometry that the generator and the reconstruction methods legitimately share, with a public API.

- :mod:`.tubes`: generalised-cylinder meshing of a skeleton (node frames, main-child choice, pipe-model radii);
- :mod:`.leaf`: the Bezier leaf of Chaurasia and Beardsley as a shape family (21 parameters), its surface,
  outline and tessellation.

Growth loops, leaf placement and species loading stay in :mod:`plantbench.generate`, which no method imports.
"""
