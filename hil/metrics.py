"""Task metrics of the iHACS paper (docs/metrics.md): max |torso lean|, max |chassis tilt|, max |speed|,
command-speed RMSE, for one plane of a run's trace."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


def paper_rmse(t: np.ndarray, commanded_rate: np.ndarray, rate: np.ndarray, time_unit: float = 1e-3) -> float:
    """The paper's equation (2) as written: (1 / (t_f − t_0)) · √(Σ (φ̇_c − φ̇)²), with t expressed in
    `time_unit` seconds (default milliseconds, which puts the magnitudes near the paper's table)."""
    span = (t[-1] - t[0]) / time_unit
    return float(math.sqrt(np.sum((commanded_rate - rate) ** 2)) / span) if span > 0 else math.nan


def rmse(commanded_rate: np.ndarray, rate: np.ndarray) -> float:
    """The conventional root-mean-square error, rad/s."""
    return float(np.sqrt(np.mean((commanded_rate - rate) ** 2)))


@dataclass(frozen=True, slots=True)
class PlaneMetrics:
    max_lean_deg: float
    max_tilt_deg: float
    max_speed: float
    rmse_paper: float
    """Paper's equation (2), t in ms, ×1e3 as in the paper's table (E-3)."""
    rmse: float
    """Conventional RMSE of the ball rate, rad/s."""


NEEDS_TELEMETRY = ("rmse", "rmse_paper")
"""Metrics that need the controller's command speed (pure/controller/telemetry): unavailable without it."""


def plane_metrics(t, lean, tilt, speed, command_speed, ball_radius: float) -> PlaneMetrics:
    """One plane's metrics; NaN where there is nothing to measure (no ticks; the RMSEs without the
    controller's telemetry)."""
    if not len(t):
        return PlaneMetrics(math.nan, math.nan, math.nan, math.nan, math.nan)
    valid = ~np.isnan(command_speed)
    commanded_rate = command_speed[valid] / ball_radius
    rate = speed[valid] / ball_radius
    told = bool(valid.any())
    return PlaneMetrics(
        max_lean_deg=float(np.degrees(np.abs(lean).max())),
        max_tilt_deg=float(np.degrees(np.abs(tilt).max())),
        max_speed=float(np.abs(speed).max()),
        rmse_paper=1e3 * paper_rmse(t[valid], commanded_rate, rate) if told else math.nan,
        rmse=rmse(commanded_rate, rate) if told else math.nan,
    )
