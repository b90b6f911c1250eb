"""Building blocks shared by the reference methods (livny, xu, guo): point-graph construction, ground removal,
allometric radii, skeleton simplification and meshing. Pure functions over numpy arrays."""
