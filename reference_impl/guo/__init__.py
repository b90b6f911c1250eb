"""guo: the reference method, Guo et al. 2018, "Realistic Procedural Plant Modeling from Multiple View Images"
(section 5, with the SIGGRAPH 2017 poster, Guo et al. 2017): point-cloud-guided procedural growth. A registered
``points`` method: it reads the ``mvs`` stage's fused cloud for view captures, or a scan's coordinates.

Modules: :mod:`.params` (constants with sources, species prior), :mod:`.weights` (Eq. 8), :mod:`.roots` (density
roots, trunk cross-section), :mod:`.hull` (Fig. 8 occluded crowns), :mod:`.growth` (L-system 1, space colonisation,
Eq. 5-7, 9, shedding), :mod:`.refine` (collapse, Hermite smoothing), :mod:`.pipeline` (the whole method on a cloud),
:mod:`.abs` (analysis-by-synthesis, Guenard et al. 2014, Eq. 3-4).

Options (a suite's ``[method_options.guo]``): every :class:`~reference_impl.guo.params.GuoParams` field by name,
plus ``prior`` (True: the species hint's parameters; False: generic defaults, to measure what the prior buys) and
``leaves`` ('auto', the default: 'combined' when ``capture_dir/depth`` holds the mvs stage's depth maps, as the
runner provides for view captures with known poses, else 'procedural'; 'procedural': leaves placed per the species
library, turned onto the cloud and kept where the cloud supports them; 'segment': the leaves that
:mod:`reference_impl.leaves` segments and fits from the views (Chaurasia and Beardsley 2017), which needs
``capture_dir/views``; 'combined': those fitted leaves plus the procedural leaves they do not cover), ``leaf_depth``
(the depth maps the leaves are segmented on: 'mvs', the default, ``capture_dir/depth`` or, without it, maps estimated
here; 'oracle', the capture's exact depth, an upper bound) and ``leaf__NAME`` for any
:class:`~reference_impl.leaves.LeafParams` field. ``candidates=k`` (k > 1) turns on analysis-by-synthesis, which
needs ``capture_dir/views``.
"""

from __future__ import annotations

from pathlib import Path

from plantbench.errors import InputError
from plantbench.io.atomic import write_json
from plantbench.io.plantio import write_reconstruction
from plantbench.schemas import jsonable
from plantbench.seeding import rng as seeded_rng
from reference_impl.common.inputs import load_points
from reference_impl.guo.params import GENERIC_PRIOR, GuoParams, SpeciesPrior, params_from_options, prior_from_hint
from reference_impl.guo.pipeline import GuoResult, reconstruct_guo

__all__ = ["Guo", "GuoParams", "GuoResult", "SpeciesPrior", "reconstruct_guo", "species_prior"]


def species_prior(species: str | None, *, prior: bool = True, hint=None) -> SpeciesPrior:
    """The prior of the species hint: ``hint`` (a :class:`plantbench.hints.SpeciesHint`, as the runner passes it in
    ``hint.json``) or the published hint of ``species`` (InputError, with suggestions, for an unknown name); the
    generic prior when there is neither or ``prior`` is False."""
    if not prior or (hint is None and species is None):
        return GENERIC_PRIOR
    if hint is None:
        from plantbench.hints import load_hint

        hint = load_hint(species)
    return prior_from_hint(hint)


def _split_options(options: dict) -> tuple[bool, str, str, dict, GuoParams]:
    """(prior, leaves, leaf_depth, leaf__ options, GuoParams) of a suite's ``[method_options.guo]``; InputError on
    an unknown or invalid one."""
    options = dict(options)
    use_prior = options.pop("prior", True)
    if not isinstance(use_prior, bool):
        raise InputError(f"guo: prior must be true or false, got {use_prior!r}")
    leaves = options.pop("leaves", "auto")
    if leaves not in ("auto", "procedural", "segment", "combined"):
        raise InputError(f"guo: leaves must be 'auto', 'procedural', 'segment' or 'combined', got {leaves!r}")
    leaf_depth = options.pop("leaf_depth", "mvs")
    if leaf_depth not in ("mvs", "oracle"):
        raise InputError(f"guo: leaf_depth must be 'mvs' or 'oracle', got {leaf_depth!r}")
    leaf_options = {k[len("leaf__"):]: options.pop(k) for k in list(options) if k.startswith("leaf__")}
    if leaves == "procedural" and (leaf_options or leaf_depth != "mvs"):
        raise InputError("guo: leaf_depth and leaf__* options need leaves='segment' or 'combined'")
    return use_prior, leaves, leaf_depth, leaf_options, params_from_options(options)


class Guo:
    name = "guo"
    inputs = "points"
    extra_options = {
        "prior": (True, "Use the species hint's procedural prior (false: the generic one)."),
        "leaves": ("auto", "'procedural', 'segment' (leaves fitted to the views), 'combined', or 'auto' (combined "
                           "when depth maps come with the cloud)."),
        "leaf_depth": ("mvs", "Depth the leaves are segmented on: 'mvs' or 'oracle' (an oracle run)."),
    }

    @property
    def options_model(self) -> dict:
        """What ``check_options`` validates and ``plantbench methods guo`` lists: its own parameters and the leaf
        stage's as ``leaf__NAME``."""
        from reference_impl.leaves import LeafParams

        return {"": GuoParams, "leaf__": LeafParams}
    oracle_when = {"leaf_depth": "oracle"}
    """``leaf_depth="oracle"`` segments the leaves on the exact depth maps: an oracle run."""

    def check_options(self, options: dict) -> None:
        """Raise InputError on an unknown or invalid option (the planner calls it before any job runs)."""
        import dataclasses

        from plantbench.schemas import unknown_options
        from reference_impl.leaves import LeafParams

        leaf_options = _split_options(options)[3]
        names = [f.name for f in dataclasses.fields(LeafParams)]
        bad = [f"leaf__{k}" for k in leaf_options if k not in names]
        if bad:
            raise InputError("guo: " + unknown_options(bad, [f"leaf__{n}" for n in names]))
        LeafParams.from_options(leaf_options)

    def reconstruct(self, capture_dir: Path, out_dir: Path, *, seed: int, species: str | None = None,
                    **options) -> GuoResult:
        """Read ``capture_dir/points.ply``, reconstruct, write skeleton.ply, mesh.ply, leaves.json (and guo.json,
        the run's statistics). Returns the in-memory result."""
        use_prior, leaves, leaf_depth, leaf_options, params = _split_options(options)
        if leaves == "auto":
            leaves = "combined" if (Path(capture_dir) / "depth").is_dir() or leaf_depth != "mvs" else "procedural"
        from plantbench.hints import read_hint

        prior = species_prior(species, prior=use_prior, hint=read_hint(capture_dir))
        points = load_points(capture_dir)
        rng = seeded_rng(seed, "guo")
        fitted, leaf_stats = None, None
        if leaves != "procedural":
            from reference_impl.leaves import LeafParams, fitted_mesh, leaves_from_capture

            found = leaves_from_capture(capture_dir, depth=leaf_depth, seed=seed, species=species,
                                        params=LeafParams.from_options(leaf_options))
            fitted = (fitted_mesh(found), found.leaves)
            leaf_stats = {"count": len(found.leaves), "skipped": found.skipped, "stats": found.stats}
        if params.candidates > 1:
            from reference_impl.guo.abs import analysis_by_synthesis, load_input_views

            cameras, images = load_input_views(capture_dir)
            result = analysis_by_synthesis(points, cameras, images, rng, params, prior, fitted,
                                           leaves == "combined")
        else:
            result = reconstruct_guo(points, rng, params, prior, fitted, leaves == "combined")
        if leaf_stats is not None:
            result.info["leaf_segmentation"] = leaf_stats
        write_reconstruction(out_dir, result.skeleton, mesh=result.mesh, leaves=result.leaves)
        write_json(Path(out_dir) / "guo.json", jsonable(result.info | {"species": prior.name}, digits=9))
        return result
