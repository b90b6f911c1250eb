"""Leaf segmentation from colour + depth and Bezier leaf fitting (Chaurasia and Beardsley 2017).

:func:`segment_and_fit` takes a view capture and per-view depth maps to fitted :class:`plantbench.plant.Leaf`
instances (section 4.1: per-view superpixels, planes, affinity graph and enclosing-ellipse confidence; section 4.2:
template ICP across views with de-duplication; section 5: Levenberg-Marquardt fit of the 21-parameter Bezier leaf of
:mod:`plantbench.geometry.leaf` with the occlusion weights of Eq. 10-11). :func:`write_leaves` writes the result.
:class:`Leaves` is the same as a method (``leaves``, inputs ``views``) that can run alone.
Heavy backends (scikit-image, Open3D, PIL) are imported inside the functions that use them.
"""

from __future__ import annotations

from pathlib import Path

from .ellipse import Ellipse, khachiyan, min_volume_ellipse, min_volume_ellipses
from .fit import LeafFit, LeafModel, fit_leaf, uv_mapping
from .params import LeafParams
from .pipeline import (
    SKIP_REASONS,
    LeafFitResult,
    fitted_mesh,
    load_depth_dir,
    segment_and_fit,
    views_folder,
    write_leaves,
)

__all__ = [
    "Leaves", "leaves_from_capture", "fitted_mesh", "LeafParams", "LeafFitResult", "LeafFit", "LeafModel", "Ellipse",
    "SKIP_REASONS", "segment_and_fit", "write_leaves", "load_depth_dir", "fit_leaf", "uv_mapping", "khachiyan", "min_volume_ellipse",
    "min_volume_ellipses",
]


def leaves_from_capture(capture_dir: Path, *, depth: str | Path = "mvs", seed: int, species: str | None = None,
                        params: LeafParams = LeafParams()) -> LeafFitResult:
    """:func:`segment_and_fit` on a capture folder (holding ``views/``) with the depth source named by ``depth``:

    - ``"mvs"``: ``capture_dir/depth`` when it exists (the mvs stage's filtered maps, ``write_depth``, which the
      runner links next to the cloud), else the mvs stage's depth maps estimated here with its default parameters;
    - ``"oracle"``: the capture's exact depth (ground truth: upper bounds only);
    - a folder of per-view maps (``NNNN.npz`` with key ``depth``, or ``NNNN.npy``).

    The species hint, when given (``capture_dir/hint.json``, as the runner writes it, else the published hint of
    ``species``), sets the mean leaf length that scales delta_plane.
    """
    from plantbench.hints import load_hint, read_hint

    capture_dir = Path(capture_dir)
    found = read_hint(capture_dir) or (load_hint(species) if species is not None else None)
    hint = None if found is None else float(found.leaf_length)
    views = views_folder(capture_dir)
    if depth == "oracle":
        return segment_and_fit(views, oracle_depth=True, leaf_length_hint=hint, seed=seed, params=params)
    if depth == "mvs" and (capture_dir / "depth").is_dir():
        depth = capture_dir / "depth"
    if depth == "mvs":
        from reference_impl.mvs import MVSParams, depth_maps, filter_depth_maps, load_views

        images, cameras, _ = load_views(capture_dir)
        mvs_params = MVSParams()
        maps, _, _ = depth_maps(images, cameras, mvs_params, seed=seed)
        depths, _ = filter_depth_maps(maps, images, cameras, mvs_params)
        return segment_and_fit(views, depths, leaf_length_hint=hint, seed=seed, params=params)
    return segment_and_fit(views, depth_dir=depth, leaf_length_hint=hint, seed=seed, params=params)


class Leaves:
    """Leaf instances from a view capture (Chaurasia and Beardsley 2017): writes ``leaves.json``, ``points.ply`` (points
    on the fitted leaf surfaces, with ``leaf_id``) and ``leaves_stats.json`` (skips per reason, timings).

    A ``points`` method: in a suite it receives the mvs stage's output (its cloud, ``views/`` and the per-view depth
    maps it estimated, ``depth/``), so the depth is estimated once per case for every method that reads it.

    Options: ``depth`` (see :func:`leaves_from_capture`: ``"mvs"``, the default, ``"oracle"`` or a folder of
    per-view maps) and any :class:`LeafParams` field.
    """

    name = "leaves"
    inputs = "points"
    options_model = LeafParams
    """What ``check_options`` validates and ``plantbench methods leaves`` lists."""
    extra_options = {"depth": ("mvs", "Depth the leaves are segmented on: 'mvs' (the mvs stage's maps), 'oracle' "
                                      "(the capture's exact depth: an oracle run) or a folder of per-view maps.")}
    oracle_when = {"depth": "oracle"}
    """``depth="oracle"`` segments on the exact depth maps: an oracle run."""

    def check_options(self, options: dict) -> None:
        """Raise InputError on an unknown or invalid option (the planner calls it before any job runs)."""
        LeafParams.from_options({k: v for k, v in options.items() if k != "depth"})

    def reconstruct(self, capture_dir: Path, out_dir: Path, *, seed: int, species: str | None = None,
                    **options) -> None:
        depth = options.pop("depth", "mvs")
        result = leaves_from_capture(capture_dir, depth=depth, seed=seed, species=species,
                                     params=LeafParams.from_options(options))
        write_leaves(out_dir, result)
