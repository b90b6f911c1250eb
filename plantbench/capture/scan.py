"""Simulated terrestrial laser scan (DESIGN.md section 5).

Each station is a scanner on a circle around the plant's axis at ``scanner_height``. It sweeps a regular grid of
beams, ``angular_step_deg`` apart in azimuth and elevation, over the angular window that the plant occupies seen
from the station (plus two steps of margin; a real scanner sweeps the full sphere, but beams that cannot reach the
plant return nothing here because the ground is not scanned). Each beam is cast against the plant's branch and leaf
meshes, so occlusion is real; the first hit within ``max_range`` returns, its range gets Gaussian noise of sigma
``range_noise``, and the return is lost with probability ``dropout``. Every point keeps its ground-truth label
(0 wood, 1 leaf), leaf id (-1 for wood) and station index. Xu et al. 2007 reconstruct from a single scan, the
default here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from plantbench.capture.raycast import RayCaster
from plantbench.capture.scene import plant_bounds
from plantbench.capture.settings import CaptureOptions
from plantbench.errors import InputError
from plantbench.plant import Plant

__all__ = ["MAX_RAYS", "Scan", "station_positions", "beam_grid", "scan_plant"]

MAX_RAYS = 30_000_000
"""Refuse stations with more beams than this (~1 GB of beam directions): the angular step is too fine for the
plant's size and distance."""


@dataclass(frozen=True)
class Scan:
    """A labelled scan.

    points : (n, 3) float; label : (n,) uint8, 0 wood 1 leaf; leaf_id : (n,) int32, -1 for wood;
    station : (n,) uint8; stations : per-station records (position, heading, angular window, beam and return counts)
    """

    points: np.ndarray
    label: np.ndarray
    leaf_id: np.ndarray
    station: np.ndarray
    stations: list[dict]


def station_positions(plant: Plant, options: CaptureOptions) -> np.ndarray:
    """(k, 3) scanner positions on a circle around the plant's bounding-box axis at ``scanner_height``."""
    lo, hi = plant_bounds(plant)
    centre = 0.5 * (lo + hi)
    radius = options.scan_distance
    if radius is None:
        radius = max(1.5 * max(float(hi[2]), float(np.max(hi[:2] - lo[:2]))), 1.0)
    az = np.radians(options.station_azimuth_deg) + 2 * np.pi * np.arange(options.stations) / options.stations
    return np.stack([centre[0] + radius * np.cos(az), centre[1] + radius * np.sin(az),
                     np.full(len(az), options.scanner_height)], axis=1)


def _window(rel: np.ndarray, heading: float, step: float) -> tuple[int, int, int, int]:
    """Integer step ranges [a0, a1] x [e0, e1] (azimuth relative to ``heading``, elevation) covering ``rel``."""
    az = np.angle(np.exp(1j * (np.arctan2(rel[:, 1], rel[:, 0]) - heading)))
    el = np.arctan2(rel[:, 2], np.hypot(rel[:, 0], rel[:, 1]))
    if np.ptp(az) > np.radians(300):  # the plant surrounds the station: sweep the full circle
        a0, a1 = -int(np.ceil(np.pi / step)), int(np.ceil(np.pi / step)) - 1
    else:
        a0, a1 = int(np.floor(az.min() / step)) - 2, int(np.ceil(az.max() / step)) + 2
    e0 = max(int(np.floor(el.min() / step)) - 2, -int(np.floor(np.pi / 2 / step)))
    e1 = min(int(np.ceil(el.max() / step)) + 2, int(np.floor(np.pi / 2 / step)))
    return a0, a1, e0, e1


def beam_grid(plant: Plant, position: np.ndarray, options: CaptureOptions) -> tuple[np.ndarray, dict]:
    """The beams of one station: a regular azimuth x elevation grid over the plant's angular window.

    Returns
    -------
    directions : (n, 3) float, unit beam directions, row-major (elevation, azimuth)
    record : heading and angular window of the station (degrees) and the beam count
    """
    lo, hi = plant_bounds(plant)
    centre = 0.5 * (lo + hi)
    pos = np.asarray(position, float)
    verts = np.concatenate([plant.branch_mesh.vertices, plant.leaf_mesh.vertices])
    step = np.radians(options.angular_step_deg)
    heading = float(np.arctan2(centre[1] - pos[1], centre[0] - pos[0]))
    a0, a1, e0, e1 = _window(verts - pos, heading, step)
    n_rays = (a1 - a0 + 1) * (e1 - e0 + 1)
    if n_rays > MAX_RAYS:
        raise InputError(f"scan: {n_rays} beams per station at angular step {options.angular_step_deg} deg "
                         f"(limit {MAX_RAYS}); use a larger angular_step_deg")
    az = heading + step * np.arange(a0, a1 + 1)
    el = step * np.arange(e0, e1 + 1)
    ce, se = np.cos(el)[:, None], np.sin(el)[:, None]
    dirs = np.stack([ce * np.cos(az)[None, :], ce * np.sin(az)[None, :], np.broadcast_to(se, (len(el), len(az)))],
                    axis=-1).reshape(-1, 3)
    record = {
        "position": pos.tolist(), "heading_deg": float(np.degrees(heading)),
        "azimuth_range_deg": [float(np.degrees(az[0])), float(np.degrees(az[-1]))],
        "elevation_range_deg": [float(np.degrees(el[0])), float(np.degrees(el[-1]))],
        "beams": int(n_rays),
    }
    return dirs, record


def scan_plant(plant: Plant, options: CaptureOptions, rng: np.random.Generator,
               caster: RayCaster | None = None) -> Scan:
    """Scan ``plant`` from ``options.stations`` stations; noise and dropout drawn from ``rng``.

    ``caster`` must index the branch faces, then the leaf faces (the default builds it); faces after those (e.g.
    the ground of :func:`plantbench.capture.views.ground_truth_caster`) stop a beam without a return.
    """
    bm, lm = plant.branch_mesh, plant.leaf_mesh
    nb = len(bm.faces)
    if caster is None:
        caster = RayCaster([(bm.vertices, bm.faces), (lm.vertices, lm.faces)])
    face_label = np.concatenate([np.zeros(nb, np.uint8), np.ones(len(lm.faces), np.uint8)])
    face_leaf = np.concatenate([np.full(nb, -1, np.int32), plant.leaf_mesh_ids.astype(np.int32)])
    out_p, out_l, out_id, out_s, records = [], [], [], [], []
    for k, pos in enumerate(station_positions(plant, options)):
        dirs, record = beam_grid(plant, pos, options)
        t, prim = caster.cast(pos, dirs, tmax=options.max_range)
        hit = np.flatnonzero((prim >= 0) & (prim < len(face_label)))
        noise = rng.normal(0.0, options.range_noise, len(hit))  # drawn even when sigma = 0: same dropout stream
        kept = rng.random(len(hit)) >= options.dropout
        hit, r = hit[kept], (t[hit] + noise)[kept]
        out_p.append(pos + r[:, None] * dirs[hit])
        out_l.append(face_label[prim[hit]])
        out_id.append(face_leaf[prim[hit]])
        out_s.append(np.full(len(hit), k, np.uint8))
        records.append({"id": k, **record, "hits": int(kept.size), "returns": int(len(hit))})
    return Scan(np.concatenate(out_p), np.concatenate(out_l), np.concatenate(out_id), np.concatenate(out_s), records)
