"""livny: the Livny et al. 2010-style baseline (docs/design.md, Shipped methods), a registered ``points`` method.

The algorithm lives in :mod:`reference_impl.livny.bsg` (pure functions, parameters with their sources in
:class:`~reference_impl.livny.bsg.LivnyParams`); this class reads the input cloud and writes the output contract.
Suite options (``[method_options.livny]``) override LivnyParams fields by name.
"""

from __future__ import annotations

from pathlib import Path

from plantbench.io.plantio import write_reconstruction
from plantbench.seeding import rng as seeded_rng
from reference_impl.common.inputs import load_points
from reference_impl.common.method import ParamsMethod
from reference_impl.livny.bsg import LivnyParams, LivnyResult, reconstruct_livny

__all__ = ["Livny", "LivnyParams", "reconstruct_livny"]


class Livny(ParamsMethod):
    name = "livny"
    options_model = LivnyParams
    """What ``check_options`` validates and ``plantbench methods livny`` lists."""

    def reconstruct(self, capture_dir: Path, out_dir: Path, *, seed: int, species: str | None = None,
                    **options) -> LivnyResult:
        """Read ``capture_dir/points.ply``, reconstruct, write skeleton.ply, mesh.ply and leaves.json.

        ``species`` is ignored (Livny et al. use no species knowledge). Returns the in-memory result.
        """
        params = self.params(options)
        points = load_points(capture_dir)
        result = reconstruct_livny(points, seeded_rng(seed, "livny"), params)
        write_reconstruction(out_dir, result.skeleton, mesh=result.mesh, leaves=result.leaves)
        return result
