"""Observed wood: which part of the ground-truth branch surface a capture showed (issue 63).

Ground truth written beside the capture's exact maps (``views/observed_wood.npz``, ``scan/observed_wood.npz``;
never in a method's input, :data:`plantbench.methods.inputs.GROUND_TRUTH`): for each ground-truth skeleton edge
(``Skeleton.edges`` order), the share of its branch surface the capture observed. The skeleton metrics split the
truth's wood by it into what a method saw and what it had to infer (``skeleton.vf1_observed@1%``,
``skeleton.vrecall_hidden@1%``, ``capture.observed_wood_share``).

- The branch surface: each edge's frustum (its two nodes' radii) sampled on a grid of :data:`AROUND` directions and
  steps of :data:`STEP_FRACTION` of the plant's height along it (:func:`wood_samples`), each sample carrying the
  area it stands for and its outward normal.
- Views (:func:`observed_in_views`): a sample is observed in a view where it faces the camera, its branch's
  projected diameter is at least ``min_diameter_px`` pixels, and it projects onto a wood pixel of the exact instance
  map whose exact depth agrees with its own within ``depth_tolerance`` of it (nothing in front of it: a leaf, another
  branch); observed by the capture when observed in at least ``min_views`` views (what multi-view stereo needs).
- Scans (:func:`observed_in_scan`): a sample is observed when a wood return lies within the tolerance of it (twice
  the scan's median spacing): the scanner's beam reached that bark.

NICE-SLAM's and Go-Surf's evaluations cull the ground-truth mesh to what the cameras saw (frustum and a depth test
against the rendered ground-truth depth) in the same way, for the same reason.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from plantbench.geometry.vectors import perpendicular, unit
from plantbench.plant import Skeleton

__all__ = ["AROUND", "STEP_FRACTION", "DEPTH_TOLERANCE", "MIN_VIEWS", "MIN_DIAMETER_PX", "OBSERVED_FILE",
           "WoodSamples", "wood_samples", "observed_in_views", "observed_in_scan", "edge_shares",
           "write_observed", "read_observed", "observed_share"]

AROUND = 8
"""Samples around each edge's circumference."""
STEP_FRACTION = 0.002
"""Step of the samples along an edge, a fraction of the plant's height (2 mm on a 1 m plant)."""
DEPTH_TOLERANCE = 0.01
"""A view's exact depth agrees with a sample's within this fraction of the sample's depth (1 %, the tolerance of
the issue's measurements of what the mvs stage keeps)."""
MIN_VIEWS = 2
"""Views in which a sample must be observed (a depth needs a second view to be triangulated)."""
MIN_DIAMETER_PX = 1.0
"""A branch thinner than this many pixels in a view is not observed there."""
OBSERVED_FILE = "observed_wood.npz"
"""The file, in ``views/`` and ``scan/``: ``share`` (e,) float32 per ground-truth edge, ``edges`` (e, 2)."""


@dataclass(frozen=True)
class WoodSamples:
    """Samples of a skeleton's branch surface.

    points, normals : (n, 3); area : (n,) m^2 each stands for; radius : (n,) its branch's radius there;
    edge : (n,) index into ``Skeleton.edges``
    """

    points: np.ndarray
    normals: np.ndarray
    area: np.ndarray
    radius: np.ndarray
    edge: np.ndarray


def wood_samples(skeleton: Skeleton, *, step: float, around: int = AROUND) -> WoodSamples:
    """The branch surface of every edge of ``skeleton`` (a frustum between its nodes' radii), sampled every
    ``step`` metres along it (at least once) and at ``around`` directions about it, each row of directions turned by
    half a step from the previous."""
    e = skeleton.edges
    if len(e) == 0 or not step > 0:
        z = np.zeros((0, 3))
        return WoodSamples(z, z, np.zeros(0), np.zeros(0), np.zeros(0, np.int64))
    pos, rad = skeleton.positions, skeleton.radii
    p0, r0 = pos[e[:, 0]], rad[e[:, 0]]
    d = pos[e[:, 1]] - p0
    length = np.linalg.norm(d, axis=1)
    axis = unit(np.where(length[:, None] > 0, d, [0.0, 0.0, 1.0]))
    u = perpendicular(axis)
    v = np.cross(axis, u)
    n = np.maximum(1, np.ceil(length / step).astype(np.int64))
    seg = np.repeat(np.arange(len(e)), n)
    row = np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n)
    t = (row + 0.5) / n[seg]
    r = r0[seg] + t * (rad[e[:, 1]] - r0)[seg]
    phi = (np.arange(around)[None, :] + 0.5 * (row % 2)[:, None]) * (2 * np.pi / around)
    normal = (np.cos(phi)[..., None] * u[seg][:, None, :] + np.sin(phi)[..., None] * v[seg][:, None, :])
    centre = p0[seg] + t[:, None] * d[seg]
    points = centre[:, None, :] + r[:, None, None] * normal
    area = np.repeat(2 * np.pi * r * length[seg] / n[seg] / around, around)
    return WoodSamples(points.reshape(-1, 3), normal.reshape(-1, 3), area, np.repeat(r, around),
                       np.repeat(seg, around))


def observed_in_views(samples: WoodSamples, cameras: list, depths: list[np.ndarray], instances: list[np.ndarray],
                      *, depth_tolerance: float = DEPTH_TOLERANCE, min_views: int = MIN_VIEWS,
                      min_diameter_px: float = MIN_DIAMETER_PX) -> np.ndarray:
    """(n,) bool: each sample observed in at least ``min_views`` of the views (``cameras``, their exact z-depth
    maps and instance maps, wood = 1): facing the camera, its branch at least ``min_diameter_px`` wide, on a wood
    pixel (nearest pixel centre) whose depth agrees within ``depth_tolerance`` of the sample's."""
    count = np.zeros(len(samples.points), np.int32)
    for cam, depth, inst in zip(cameras, depths, instances, strict=True):
        uv, z = cam.project(samples.points)
        facing = np.einsum("ij,ij->i", samples.normals, cam.center[None, :] - samples.points) > 0
        with np.errstate(divide="ignore", invalid="ignore"):
            wide = 2.0 * samples.radius * float(cam.K[0, 0]) / z >= min_diameter_px
        px = np.rint(uv).astype(np.int64, copy=False) if len(uv) else np.zeros((0, 2), np.int64)
        inside = (z > 0) & facing & wide & (px[:, 0] >= 0) & (px[:, 0] < cam.width) & (px[:, 1] >= 0) \
            & (px[:, 1] < cam.height)
        i = np.flatnonzero(inside)
        pu, pv = px[i, 0], px[i, 1]
        ok = (inst[pv, pu] == 1) & (np.abs(depth[pv, pu] - z[i]) <= depth_tolerance * z[i])
        count[i[ok]] += 1
    return count >= min_views


def observed_in_scan(samples: WoodSamples, wood_returns: np.ndarray, tolerance: float) -> np.ndarray:
    """(n,) bool: each sample within ``tolerance`` metres of a wood return of the scan."""
    from scipy.spatial import cKDTree

    if len(wood_returns) == 0 or len(samples.points) == 0:
        return np.zeros(len(samples.points), bool)
    d, _ = cKDTree(wood_returns).query(samples.points, distance_upper_bound=tolerance)
    return np.isfinite(d)


def edge_shares(samples: WoodSamples, observed: np.ndarray, n_edges: int) -> np.ndarray:
    """(n_edges,) the area-weighted share of each edge's samples that are ``observed`` (0 for an edge of no area)."""
    total = np.bincount(samples.edge, weights=samples.area, minlength=n_edges)
    seen = np.bincount(samples.edge, weights=samples.area * observed, minlength=n_edges)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(total > 0, seen / np.where(total > 0, total, 1.0), 0.0)


def write_observed(path: str | Path, skeleton: Skeleton, share: np.ndarray, params: dict) -> None:
    """``share`` (one per edge of ``skeleton``) and the edges they belong to, written atomically as npz."""
    from plantbench.io.atomic import atomic_write

    with atomic_write(path) as f:
        np.savez_compressed(f, share=np.asarray(share, np.float32), edges=skeleton.edges.astype(np.int64),
                            **{f"param_{k}": np.asarray(v) for k, v in params.items()})


def read_observed(path: str | Path, skeleton: Skeleton) -> np.ndarray:
    """The per-edge observed share written by :func:`write_observed`, checked against ``skeleton``'s edges."""
    from plantbench.errors import InputError

    try:
        with np.load(path) as z:
            share, edges = z["share"].astype(float), z["edges"]
    except (OSError, KeyError, ValueError) as exc:
        raise InputError(f"not an observed-wood file ({exc})", path=path) from exc
    if edges.shape != skeleton.edges.shape or not np.array_equal(edges, skeleton.edges):
        raise InputError("its edges are not the ground-truth skeleton's (a capture of another plant?)", path=path)
    if share.shape != (len(edges),) or not np.all((share >= 0) & (share <= 1)):
        raise InputError("share must hold one value in [0, 1] per edge", path=path)
    return share


def observed_share(skeleton: Skeleton, share: np.ndarray) -> float:
    """The volume-weighted share of the skeleton's wood observed: sum(pi r^2 L share) / sum(pi r^2 L) over the
    edges, r the mean of the edge's two radii (0 for a skeleton without wood)."""
    e = skeleton.edges
    if len(e) == 0:
        return 0.0
    r = 0.5 * (skeleton.radii[e[:, 0]] + skeleton.radii[e[:, 1]])
    w = np.pi * r**2 * np.linalg.norm(skeleton.positions[e[:, 1]] - skeleton.positions[e[:, 0]], axis=1)
    return float((w * share).sum() / w.sum()) if w.sum() > 0 else 0.0
