"""Rig calibration: the geometry plantsim assumes, estimated from a scan of the calibration target.

A raw record of the calibration target (:mod:`plantsim.plant.target`) on the
rig holds ranges, beam angles and encoder readings. With the right rig geometry
every return lies on the target's known surface (or the disk's top). The fit
finds the geometry that puts them there: nonlinear least squares
(``scipy.optimize.least_squares``, a soft-L1 loss so that the bench, the post and
stray returns do not pull) on the exact signed distance of each reconstructed
point to the target, over

- ``lidar_distance_m``: the optical centre's distance from the axis,
- ``lidar_height_m``: its height above the disk top,
- ``tilt_deg``: the fan turned within its plane. This is also the LiDAR's angular
  offset (a beam-angle zero that is off): the two are one rotation and cannot
  be told apart, so one number stands for both;
- ``yaw_deg``: the scan plane turned about the vertical (off the axis),
- ``roll_deg``: the scan plane leaned about the boresight,
- ``encoder_offset_deg``: what the encoder reads with the table at angle 0.

The uncertainties are one standard deviation from the fit's Jacobian
(covariance = s^2 (J^T J)^-1 over the points the loss keeps, s^2 their residual
variance); they say how well the data pin each parameter, not how right the
target's sizes are. Which parameters the target makes observable and how well
(measured over perturbed rigs with the realistic sensor) is in
``docs/calibration.md`` (``scripts/calibration_study.py``).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from plantsim.cloud.reconstruct import base_to_turntable, points_base_from_ranges
from plantsim.plant.target import CALIBRATION_TARGET, CalibrationTarget, ray_distance
from plantsim.rig.geometry import RigGeometry
from plantsim.scan.raw import RawScan
from plantsim.sensor.spec import BeamStatus

PARAMETERS = ("lidar_distance_m", "lidar_height_m", "tilt_deg", "yaw_deg", "roll_deg", "encoder_offset_deg")
# Finite-difference steps and the scale of each parameter (metres and degrees).
_SCALE = np.array([1e-3, 1e-3, 0.1, 0.1, 0.1, 0.1])
# How far from the starting geometry the fit may go: 5 cm, 10 degrees, half a turn of offset.
_BOUNDS = np.array([0.05, 0.05, 10.0, 10.0, 10.0, 200.0])


@dataclasses.dataclass(frozen=True)
class Calibration:
    """A fitted rig.

    Attributes:
      rig: the nominal geometry with the fitted parameters.
      std: one standard deviation of each fitted parameter (same units).
      rms_m: RMS distance to the target of the points the fit kept, metres.
      n_points: points used; n_kept: of them, within 3 robust scales of the surface.
      start: the geometry the fit started from.
    """

    rig: RigGeometry
    std: dict
    rms_m: float
    n_points: int
    n_kept: int
    start: RigGeometry

    def to_dict(self) -> dict:
        return {"fitted": {k: getattr(self.rig, k) for k in PARAMETERS}, "std": self.std, "rms_m": self.rms_m,
                "n_points": self.n_points, "n_kept": self.n_kept,
                "start": {k: getattr(self.start, k) for k in PARAMETERS}}


def _rig_with(nominal: RigGeometry, x: np.ndarray) -> RigGeometry:
    return dataclasses.replace(nominal, **{k: float(v) for k, v in zip(PARAMETERS, x)})


def _points(raw: RawScan, rig: RigGeometry, lines: np.ndarray, beams: np.ndarray, readings_rad: np.ndarray
            ) -> np.ndarray:
    """Turntable-frame points of the chosen returns under a rig geometry."""
    base = points_base_from_ranges(raw.range_m[lines, beams], raw.beam_angle_rad[beams], rig.T_base_lidar())
    return base_to_turntable(base, readings_rad - math.radians(rig.encoder_offset_deg))


def calibrate(raw: RawScan, *, nominal: RigGeometry = RigGeometry(), target: CalibrationTarget = CALIBRATION_TARGET,
              max_points: int = 30_000, loss_scale_m: float = 0.003, seed: int = 0) -> Calibration:
    """Fits the rig geometry to a raw record of the calibration target.

    Args:
      raw: the raw record (simulated, or from a real rig's bag).
      nominal: where to start, and the fixed geometry (disk size); its
        ``encoder_offset_deg`` is the starting offset.
      target: the target's sizes.
      max_points: returns used at most (a fixed random subset of those near the target).
      loss_scale_m: the soft-L1 loss's scale: residuals beyond a few of these count little.
      seed: the subset's seed.

    Raises:
      ValueError: too few returns near the target to fit six parameters.
    """
    from scipy.optimize import least_squares

    ok = raw.status == BeamStatus.OK
    lines, beams = np.nonzero(ok)
    # The angle the rig believes, as it would be read with no encoder offset.
    readings = raw.turntable_angle_rad[lines, beams] + raw.encoder_offset_rad
    # Keep returns near the target under the nominal rig: within its bounding cylinder, with margin.
    reach = target.drum_radius_m + target.fin_length_m + 0.03
    top = target.drum_height_m + target.post_height_m + 0.03
    p0 = _points(raw, nominal, lines, beams, readings)
    near = (np.hypot(p0[:, 0], p0[:, 1]) < min(reach, nominal.disk_radius_m)) & (p0[:, 2] > -0.02) & (p0[:, 2] < top)
    above_disk = int((near & (p0[:, 2] > 0.005)).sum())
    lines, beams, readings = lines[near], beams[near], readings[near]
    if above_disk < 200:
        raise ValueError(f"only {above_disk} returns lie near the calibration target under the starting rig "
                         f"geometry; scan the target (plant bundled = \"calibration-target\") and start from a rig "
                         f"within a few centimetres of the real one ([rig] in the configuration)")
    if len(lines) > max_points:
        keep = np.sort(np.random.default_rng(seed).choice(len(lines), max_points, replace=False))
        lines, beams, readings = lines[keep], beams[keep], readings[keep]

    a = raw.beam_angle_rad[beams]
    dirs_lidar = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=1)
    measured = raw.range_m[lines, beams]

    def residuals(z):
        # Range noise lies along the beam: compare each measured range with the range
        # to the target along the same beam under this geometry; a beam that would
        # miss the target is measured by its point's distance to the surface instead.
        rig = _rig_with(nominal, x0 + z * _SCALE)
        T = rig.T_base_lidar()
        theta = readings - math.radians(rig.encoder_offset_deg)
        c, s = np.cos(-theta), np.sin(-theta)
        o = T[:3, 3]
        origins = np.stack([c * o[0] - s * o[1], s * o[0] + c * o[1], np.full_like(c, o[2])], axis=1)
        d = dirs_lidar @ T[:3, :3].T
        dirs = np.stack([c * d[:, 0] - s * d[:, 1], s * d[:, 0] + c * d[:, 1], d[:, 2]], axis=1)
        predicted = ray_distance(target, origins, dirs, disk_radius_m=rig.disk_radius_m,
                                 disk_thickness_m=rig.disk_thickness_m)
        hit = np.isfinite(predicted)
        out = np.empty(len(measured))
        out[hit] = measured[hit] - predicted[hit]
        if not hit.all():
            miss = ~hit
            out[miss] = target.distance(origins[miss] + measured[miss, None] * dirs[miss],
                                        disk_radius_m=rig.disk_radius_m)
        return out

    x0 = np.array([getattr(nominal, k) for k in PARAMETERS], dtype=np.float64)
    # Only the fin breaks the target's symmetry, so the encoder offset has a narrow basin:
    # find it first by a search over a whole turn (the other parameters at their start).
    offset_index = PARAMETERS.index("encoder_offset_deg")
    z = np.zeros(len(PARAMETERS))
    base_scale = max(loss_scale_m, 1.5 * float(np.median(np.abs(residuals(z)))))
    best = (np.inf, 0.0)
    for step_deg, span_deg in ((2.0, 180.0), (0.25, 3.0)):
        centre = best[1]
        for offset in centre + np.arange(-span_deg, span_deg + step_deg / 2, step_deg):
            z[offset_index] = offset / _SCALE[offset_index]
            r = residuals(z) / base_scale
            cost = float(np.sum(np.log1p(r * r)))
            if cost < best[0]:
                best = (cost, offset)
    z = np.zeros(len(PARAMETERS))
    z[offset_index] = best[1] / _SCALE[offset_index]
    # The loss's scale follows the data's noise: the median absolute residual at the start
    # (a realistic sensor's ranges scatter by centimetres, an ideal one's by nothing).
    scale = max(loss_scale_m, 1.5 * float(np.median(np.abs(residuals(z)))))
    for _ in range(4):  # shrink the scale as the fit settles, down to the noise
        fit = least_squares(residuals, z, loss="cauchy", f_scale=scale, x_scale=1.0, diff_step=1e-3,
                            bounds=(-_BOUNDS / _SCALE, _BOUNDS / _SCALE), max_nfev=100)
        z = fit.x
        new_scale = max(loss_scale_m, 1.5 * float(np.median(np.abs(fit.fun))))
        if new_scale > 0.8 * scale:
            break
        scale = new_scale
    x = x0 + z * _SCALE
    res = fit.fun
    loss_scale_m = scale
    kept = np.abs(res) < 3 * loss_scale_m
    J = fit.jac[kept]
    dof = max(int(kept.sum()) - len(PARAMETERS), 1)
    s2 = float(np.sum(res[kept] ** 2) / dof)
    try:
        cov = np.linalg.inv(J.T @ J) * s2
        std = np.sqrt(np.clip(np.diag(cov), 0, None)) * _SCALE
    except np.linalg.LinAlgError:
        std = np.full(len(PARAMETERS), np.inf)
    return Calibration(rig=_rig_with(nominal, x), std={k: float(v) for k, v in zip(PARAMETERS, std)},
                       rms_m=float(np.sqrt(np.mean(res[kept] ** 2))) if kept.any() else float("nan"),
                       n_points=int(len(res)), n_kept=int(kept.sum()), start=nominal)


def rig_toml(calibration: Calibration, *, source: str = "") -> str:
    """A ``[rig]`` TOML section with the fitted geometry, the uncertainties as comments."""
    rig = calibration.rig
    lines = ["# Rig geometry fitted by `plantsim calibrate`" + (f" from {source}" if source else ""),
             f"# {calibration.n_kept:,} of {calibration.n_points:,} returns on the target; RMS "
             f"{calibration.rms_m * 1e3:.3f} mm. Uncertainties: one standard deviation of the fit.",
             "[rig]"]
    units = {"m": 1e3, "deg": 1.0}
    for name in PARAMETERS:
        unit = "m" if name.endswith("_m") else "deg"
        shown = f"{calibration.std[name] * units[unit]:.3g} {'mm' if unit == 'm' else 'deg'}"
        lines.append(f"{name} = {getattr(rig, name)!r}  # +- {shown}")
    for name in ("disk_radius_m", "disk_thickness_m", "pedestal_height_m"):
        lines.append(f"{name} = {getattr(rig, name)!r}")
    return "\n".join(lines) + "\n"
