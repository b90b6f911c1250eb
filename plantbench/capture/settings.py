"""Every parameter of a capture, in one frozen model (recorded verbatim in views/capture.json).

:class:`CaptureOptions` extends the suites' :class:`plantbench.suites.CaptureSettings` (views, size, spp,
elevation band, scan on/off, stations), so a suite's ``[capture]`` table is valid input, and adds the camera,
lighting and scanner parameters a suite does not usually change.
"""

from __future__ import annotations

from typing import Any

from pydantic import Field, ValidationError

from plantbench.errors import InputError
from plantbench.schemas import validation_message
from plantbench.suites import CaptureSettings

__all__ = ["CaptureOptions", "as_options"]


class CaptureOptions(CaptureSettings):
    """Capture parameters: the suite's :class:`CaptureSettings` plus camera, light and scanner details."""

    fov_deg: float = Field(default=40.0, gt=1.0, lt=170.0, description="horizontal field of view, degrees")
    fill: float = Field(default=0.9, gt=0.1, le=1.0,
                        description="the plant's projection spans at most this fraction of the frame (per view)")
    max_depth: int = Field(default=6, ge=1, le=64, description="path tracer: longest light path (bounces + 1)")
    sun_elevation_deg: float = Field(default=50.0, gt=0.0, le=90.0, description="sun height above the horizon")
    sun_azimuth_deg: float = Field(default=135.0, description="sun azimuth, degrees counter-clockwise from +X")
    normals: bool = Field(default=False, description="also write views/normal/NNNN.npy (world-space unit normals)")
    colmap_points: int = Field(default=4000, ge=0, le=1_000_000,
                               description="ground-truth surface samples offered to points3D.txt (those seen in >= 2 "
                                           "views are written)")
    scanner_height: float = Field(default=1.5, gt=0.0, description="scanner optical centre above the ground, metres")
    scan_distance: float | None = Field(
        default=None, gt=0.0,
        description="radius of the station circle around the plant's axis, metres; None: 1.5 x max(height, crown "
                    "width), at least 1 m")
    station_azimuth_deg: float = Field(default=-90.0, description="azimuth of the first station; others follow "
                                                                  "evenly around the circle")
    angular_step_deg: float = Field(default=0.05, gt=0.001, le=5.0,
                                    description="scanner angular step in azimuth and elevation, degrees")
    max_range: float = Field(default=100.0, gt=0.0, description="returns farther than this are lost, metres")
    range_noise: float = Field(default=0.002, ge=0.0, description="Gaussian range noise sigma, metres")
    dropout: float = Field(default=0.02, ge=0.0, lt=1.0, description="probability that a return is lost")


def as_options(settings: Any) -> CaptureOptions:
    """``settings`` (None, a dict, a suite's :class:`CaptureSettings` or :class:`CaptureOptions`) validated."""
    if isinstance(settings, CaptureOptions):
        return settings
    if settings is None:
        return CaptureOptions()
    if isinstance(settings, CaptureSettings):
        settings = settings.model_dump()
    try:
        return CaptureOptions.model_validate(dict(settings))
    except (ValidationError, TypeError, ValueError) as exc:
        msg = validation_message(exc) if isinstance(exc, ValidationError) else str(exc)
        raise InputError(f"capture settings: {msg}") from None
