"""xu: the Xu, Gossett, Chen 2007-style baseline, a registered ``points`` method.

The algorithm: :mod:`reference_impl.xu.skeleton` (section 4.1-4.2), :mod:`reference_impl.xu.synthesis` (4.3-4.4)
and :mod:`reference_impl.xu.pipeline` (the whole chain, radii and angles of section 5.2, leaves of section 6; the
parameters with their sources in :class:`~reference_impl.xu.pipeline.XuParams`). Suite options
(``[method_options.xu]``) override XuParams fields by name.
"""

from __future__ import annotations

from pathlib import Path

from plantbench.io.plantio import write_reconstruction
from plantbench.seeding import rng as seeded_rng
from reference_impl.common.inputs import load_points
from reference_impl.common.method import ParamsMethod
from reference_impl.xu.pipeline import XuParams, XuResult, reconstruct_xu

__all__ = ["Xu", "XuParams", "reconstruct_xu"]


class Xu(ParamsMethod):
    name = "xu"
    options_model = XuParams
    """What ``check_options`` validates and ``plantbench methods xu`` lists."""

    def reconstruct(self, capture_dir: Path, out_dir: Path, *, seed: int, species: str | None = None,
                    **options) -> XuResult:
        """Read ``capture_dir/points.ply``, reconstruct, write skeleton.ply, mesh.ply and leaves.json.

        The paper's lengths are scaled by the measured plant height; the one species value used is the hint's leaf
        length (``hint.json``), as the leaf-location cell and the support distance d0 (``XuParams.leaf_size``, the
        paper's "sphere ... based on leaf or leaf cluster size for the tree species in question"), unless the
        options set ``leaf_size``. Without a hint both are scaled from the height. Returns the in-memory result.
        """
        from plantbench.hints import read_hint

        hint = read_hint(capture_dir)
        if hint is not None and "leaf_size" not in options:
            options = {**options, "leaf_size": hint.leaf_length}
        params = self.params(options)
        points = load_points(capture_dir)
        result = reconstruct_xu(points, seeded_rng(seed, "xu"), params)
        write_reconstruction(out_dir, result.skeleton, mesh=result.mesh, leaves=result.leaves)
        return result
