"""Simulated terrestrial laser scan (docs/design.md, Capture).

Each station is a scanner on a circle around the plant's axis at ``scanner_height``. It sweeps a regular grid of
beams, ``angular_step_deg`` apart in azimuth and elevation, over the angular window that the plant occupies seen
from the station (plus two steps of margin; a real scanner sweeps the full sphere, but beams that cannot reach the
plant return nothing here because the ground is not scanned). Each beam is cast against the plant's branch and leaf
meshes, so occlusion is real; the first hit within ``max_range`` returns, its range r gets Gaussian noise of sigma
``range_noise + range_noise_per_m * r``, and the return is lost with probability ``dropout``. Every point keeps its
ground-truth label (0 wood, 1 leaf), leaf id (-1 for wood) and station index. Xu et al. 2007 reconstruct from a
single scan, the default here.

Field scans are sparser and rougher than the default scanner: ``scan_spacing`` sets the angular step from the
beam spacing wanted at the plant (spacing / station distance, so the density comes from the scanner's geometry, not
from thinning a dense cloud), and ``registration_error`` misregisters every station after the first by a random
rigid transform, as the registration of real multi-station scans leaves them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from plantbench.capture.raycast import RayCaster
from plantbench.capture.scene import plant_bounds
from plantbench.capture.settings import CaptureOptions
from plantbench.errors import InputError
from plantbench.geometry.clouds import median_spacing
from plantbench.plant import Plant

__all__ = ["MAX_RAYS", "Scan", "station_positions", "station_distance", "angular_step", "beam_grid",
           "misregistration", "median_spacing", "scan_plant"]

MAX_RAYS = 30_000_000
"""Refuse stations with more beams than this (~1 GB of beam directions): the angular step is too fine for the
plant's size and distance."""


@dataclass(frozen=True)
class Scan:
    """A labelled scan.

    points : (n, 3) float; label : (n,) uint8, 0 wood 1 leaf; leaf_id : (n,) int32, -1 for wood;
    station : (n,) uint8; stations : per-station records (position, heading, angular window, angular step, beam and
    return counts; for a misregistered station also ``misregistration``: rotation, offset, RMS displacement of its
    points and true position, which is ground truth)
    """

    points: np.ndarray
    label: np.ndarray
    leaf_id: np.ndarray
    station: np.ndarray
    stations: list[dict]


def station_distance(plant: Plant, options: CaptureOptions) -> float:
    """Radius of the station circle, metres: ``scan_distance``, or 1.5 x max(height, crown width), at least 1 m."""
    if options.scan_distance is not None:
        return float(options.scan_distance)
    lo, hi = plant_bounds(plant)
    return max(1.5 * max(float(hi[2]), float(np.max(hi[:2] - lo[:2]))), 1.0)


def angular_step(plant: Plant, options: CaptureOptions) -> float:
    """The scanner's angular step, radians: ``scan_spacing`` / station distance, or ``angular_step_deg``."""
    if options.scan_spacing is not None:
        return float(options.scan_spacing) / station_distance(plant, options)
    return float(np.radians(options.angular_step_deg))


def station_positions(plant: Plant, options: CaptureOptions) -> np.ndarray:
    """(k, 3) scanner positions on a circle around the plant's bounding-box axis at ``scanner_height``."""
    lo, hi = plant_bounds(plant)
    centre = 0.5 * (lo + hi)
    radius = station_distance(plant, options)
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
    step = angular_step(plant, options)
    heading = float(np.arctan2(centre[1] - pos[1], centre[0] - pos[0]))
    a0, a1, e0, e1 = _window(verts - pos, heading, step)
    n_rays = (a1 - a0 + 1) * (e1 - e0 + 1)
    if n_rays > MAX_RAYS:
        raise InputError(f"scan: {n_rays} beams per station at angular step {np.degrees(step):.4g} deg "
                         f"(limit {MAX_RAYS}); use a larger angular_step_deg or scan_spacing")
    az = heading + step * np.arange(a0, a1 + 1)
    el = step * np.arange(e0, e1 + 1)
    ce, se = np.cos(el)[:, None], np.sin(el)[:, None]
    dirs = np.stack([ce * np.cos(az)[None, :], ce * np.sin(az)[None, :], np.broadcast_to(se, (len(el), len(az)))],
                    axis=-1).reshape(-1, 3)
    record = {
        "position": pos.tolist(), "heading_deg": float(np.degrees(heading)),
        "azimuth_range_deg": [float(np.degrees(az[0])), float(np.degrees(az[-1]))],
        "elevation_range_deg": [float(np.degrees(el[0])), float(np.degrees(el[-1]))],
        "angular_step_deg": float(np.degrees(step)),
        "beams": int(n_rays),
    }
    return dirs, record


def misregistration(plant: Plant, rms: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A random rigid transform x -> R (x - c) + c + t whose displacement of the plant's mesh vertices has an RMS of
    about ``rms`` metres: half of the variance from a rotation about a random axis through the plant's bounding-box
    centre c, half from a translation t. Returns (R (3, 3), offset (3,)) with x -> x @ R.T + offset."""
    lo, hi = plant_bounds(plant)
    centre = 0.5 * (lo + hi)
    verts = np.concatenate([plant.branch_mesh.vertices, plant.leaf_mesh.vertices])
    # a rotation by a small angle a about a random axis moves a point at distance rho from the axis by ~ a * rho;
    # E[rho^2] over random axes is 2/3 of the mean squared distance from the centre
    rho = np.sqrt(2.0 / 3.0 * np.mean(np.sum((verts - centre) ** 2, axis=1))) if len(verts) else 1.0
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    angle = rng.normal() * rms / np.sqrt(2.0) / max(rho, 1e-6)
    t = rng.normal(size=3) * rms / np.sqrt(6.0)
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    rot = np.eye(3) + np.sin(angle) * k + (1.0 - np.cos(angle)) * (k @ k)
    return rot, centre - rot @ centre + t


def scan_plant(plant: Plant, options: CaptureOptions, rng: np.random.Generator,
               caster: RayCaster | None = None, registration_rng: np.random.Generator | None = None) -> Scan:
    """Scan ``plant`` from ``options.stations`` stations; noise and dropout drawn from ``rng``, the
    misregistration of the stations after the first (``options.registration_error``) from ``registration_rng``
    (default: a generator spawned from ``rng``).

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
        sigma = options.range_noise + options.range_noise_per_m * t[hit]
        noise = rng.normal(0.0, sigma, len(hit))  # drawn even when sigma = 0: same dropout stream
        kept = rng.random(len(hit)) >= options.dropout
        hit, r = hit[kept], (t[hit] + noise)[kept]
        points = pos + r[:, None] * dirs[hit]
        if k > 0 and options.registration_error > 0:
            if registration_rng is None:
                registration_rng = rng.spawn(1)[0]
            rot, offset = misregistration(plant, options.registration_error, registration_rng)
            moved = points @ rot.T + offset
            rms = float(np.sqrt(np.mean(np.sum((moved - points) ** 2, axis=1)))) if len(points) else 0.0
            # the registered scan places the station where the misregistration moved it; the truth is ground truth
            record["misregistration"] = {"rotation": rot.tolist(), "offset": offset.tolist(), "rms": rms,
                                         "true_position": record["position"]}
            record["position"] = (np.asarray(record["position"]) @ rot.T + offset).tolist()
            points = moved
        out_p.append(points)
        out_l.append(face_label[prim[hit]])
        out_id.append(face_leaf[prim[hit]])
        out_s.append(np.full(len(hit), k, np.uint8))
        records.append({"id": k, **record, "hits": int(kept.size), "returns": int(len(hit))})
    return Scan(np.concatenate(out_p), np.concatenate(out_l), np.concatenate(out_id), np.concatenate(out_s), records)
