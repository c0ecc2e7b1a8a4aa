"""Rig calibration: the geometry plantsim assumes, estimated from a scan of the calibration target.

A raw record of the calibration target (:mod:`plantsim.plant.target`) on the
rig holds ranges, beam angles and encoder readings. With the right rig geometry
every measured range equals the range along the same beam to the target's known
surface (or the disk's top), plus the sensor's noise. The fit is one joint
nonlinear least-squares problem (``scipy.optimize.least_squares``, Cauchy loss)
on those range residuals over the rig's parameters

- ``lidar_distance_m``: the optical centre's distance from the axis,
- ``lidar_height_m``: its height above the disk top,
- ``tilt_deg``: the fan turned within its plane. This is also the LiDAR's angular
  offset (a beam-angle zero that is off): the two are one rotation and cannot
  be told apart, so one number stands for both;
- ``yaw_deg``: the scan plane turned about the vertical (off the axis),
- ``roll_deg``: the scan plane leaned about the boresight,
- ``encoder_offset_deg``: what the encoder reads with the table at angle 0
  (continuous in the fit; a search over the whole turn only finds its basin),

and three nuisance parameters a real rig has but a scan must not depend on
(:data:`NUISANCE`): the LiDAR's range offset (a per-unit, per-material bias,
which would otherwise be read as a distance), and where the target stands on the
disk (its centre's x and y in the turntable frame).

Noise is along the beam, so the residual is a range, not a point-to-surface
distance. Only beams whose predicted return lies inside one smooth surface are
used: beams near a silhouette, a corner or the disk's rim (where the real
footprint mixes surfaces, and where the sensor drops EDGE returns) and beams at
grazing incidence are left out, chosen by the model's prediction and never by
the measured point, so the choice does not bias the ranges it keeps. The
choice is made again as the fit settles.

The uncertainties are one standard deviation from the fit's Jacobian
(covariance = s^2 (J^T J)^-1 over the beams the loss keeps, s^2 their residual
variance); they say how well the data pin each parameter, not how right the
target's sizes are. ``docs/calibration.md`` has what the target makes
observable and a study over perturbed rigs with the realistic sensor
(``scripts/calibration_study.py``), including how well these uncertainties cover
the actual errors.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Mapping
from types import MappingProxyType

import numpy as np

from plantsim.cloud.reconstruct import base_to_turntable, points_base_from_ranges
from plantsim.plant.target import (
    CALIBRATION_TARGET,
    CalibrationTarget,
    ray_hit,
    surface_normals,
)
from plantsim.rig.geometry import RigGeometry
from plantsim.scan.raw import RawScan
from plantsim.sensor.spec import BeamStatus

log = logging.getLogger(__name__)

PARAMETERS = ("lidar_distance_m", "lidar_height_m", "tilt_deg", "yaw_deg", "roll_deg", "encoder_offset_deg")
NUISANCE = ("range_offset_m", "target_x_m", "target_y_m")
_ALL = PARAMETERS + NUISANCE
# The scale of each parameter (metres and degrees): the fit's variables are the
# parameters in these units, so that a step of 1 means the same to each.
_SCALE = np.array([1e-3, 1e-3, 0.1, 0.1, 0.1, 0.1, 1e-3, 1e-3, 1e-3])
# How far from the starting geometry the fit may go: 5 cm, 10 degrees, 3 cm of range offset and placement.
# The encoder offset is free (its basin is found by a search over the whole turn).
_BOUNDS = np.array([0.05, 0.05, 10.0, 10.0, 10.0, np.inf, 0.03, 0.03, 0.03])
# A parameter is reported observable when the data pin it to within this (1 sigma).
OBSERVABLE_STD = {"lidar_distance_m": 0.002, "lidar_height_m": 0.002, "tilt_deg": 0.3, "yaw_deg": 0.3,
                  "roll_deg": 0.3, "encoder_offset_deg": 0.3, "range_offset_m": 0.002, "target_x_m": 0.002,
                  "target_y_m": 0.002}
# A sensor's systematic share of each parameter's error (1 sigma, same units), added in
# quadrature to the fit's statistical sigma: what independent range noise leaves out. For
# the simulated URG-04LX on the shipped target it is none: over 18 random rigs of
# scripts/calibration_study.py (0.25-degree steps) the statistical sigma alone covers the
# errors (RMS error/sigma 0.57-1.16 for every parameter, docs/calibration.md). It stays a
# parameter (``calibrate(model_std=...)``) for a sensor or target whose study says otherwise.
MODEL_STD: Mapping[str, float] = MappingProxyType({})

# The final round is repeated until fewer than this share of the beams change their choice.
_SETTLED_BEAMS = 1e-3
_MAX_FINAL_ROUNDS = 6

# Beams whose predicted hit meets the surface at more than this incidence are left out:
# there the footprint smears over centimetres of surface and its range is biased.
_MAX_TAN_INCIDENCE = 3.0


@dataclasses.dataclass(frozen=True)
class Calibration:
    """A fitted rig.

    Attributes:
      rig: the nominal geometry with the fitted parameters.
      std: one standard deviation of each fitted parameter and nuisance (same units): the
        fit's statistical sigma and the sensor model's systematic share
        (:data:`MODEL_STD`, or what ``calibrate(model_std=...)`` was given) in quadrature.
      std_fit: the statistical sigma alone (independent range noise, range offset as told).
      nuisance: the fitted range offset (metres, measured minus true) and target placement (metres).
      observable: per parameter, whether the data pin it (std below :data:`OBSERVABLE_STD`).
      correlation: (9, 9) correlation of the parameters, :data:`PARAMETERS` + :data:`NUISANCE` order.
      rms_m: RMS range residual of the beams the fit kept, metres.
      n_points: beams used; n_kept: of them, within 3 robust standard deviations.
      start: the geometry the fit started from.
    """

    rig: RigGeometry
    std: dict
    std_fit: dict
    nuisance: dict
    observable: dict
    correlation: np.ndarray
    rms_m: float
    n_points: int
    n_kept: int
    start: RigGeometry

    def to_dict(self) -> dict:
        return {"fitted": {k: getattr(self.rig, k) for k in PARAMETERS}, "nuisance": self.nuisance,
                "std": self.std, "std_fit": self.std_fit, "observable": self.observable, "rms_m": self.rms_m,
                "n_points": self.n_points, "n_kept": self.n_kept,
                "start": {k: getattr(self.start, k) for k in PARAMETERS}}


def _rig_with(nominal: RigGeometry, x: np.ndarray) -> RigGeometry:
    return dataclasses.replace(nominal, **{k: float(v) for k, v in zip(PARAMETERS, x)})


@dataclasses.dataclass(frozen=True)
class _Beams:
    """The returns the fit may use: (n,) arrays."""

    range_m: np.ndarray
    beam_angle_rad: np.ndarray
    reading_rad: np.ndarray  # the encoder's reading (the believed angle plus the recorded offset)


def _rays(beams: _Beams, nominal: RigGeometry, x: np.ndarray, *, d_beam_rad: float = 0.0, d_table_rad: float = 0.0
          ) -> tuple[np.ndarray, np.ndarray]:
    """Beam origins and directions in the target's frame (the turntable frame, shifted to the target's centre)."""
    rig = _rig_with(nominal, x)
    T = rig.T_base_lidar()
    a = beams.beam_angle_rad + d_beam_rad
    dirs_lidar = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=1)
    theta = beams.reading_rad - math.radians(rig.encoder_offset_deg) + d_table_rad
    c, s = np.cos(-theta), np.sin(-theta)
    o = T[:3, 3]
    shift = x[len(PARAMETERS) + 1:]
    origins = np.stack([c * o[0] - s * o[1] - shift[0], s * o[0] + c * o[1] - shift[1], np.full_like(c, o[2])], axis=1)
    d = dirs_lidar @ T[:3, :3].T
    dirs = np.stack([c * d[:, 0] - s * d[:, 1], s * d[:, 0] + c * d[:, 1], d[:, 2]], axis=1)
    return origins, dirs


def _predict(beams: _Beams, nominal: RigGeometry, target: CalibrationTarget, x: np.ndarray, **shift
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    origins, dirs = _rays(beams, nominal, x, **shift)
    t, surface = ray_hit(target, origins, dirs, disk_radius_m=nominal.disk_radius_m,
                         disk_thickness_m=nominal.disk_thickness_m)
    return t, surface, origins, dirs


def _residuals(beams: _Beams, nominal: RigGeometry, target: CalibrationTarget, x: np.ndarray) -> np.ndarray:
    """Measured minus predicted range (with the range offset), metres. A beam that would miss
    under this geometry is measured by its point's distance to the surface instead (continuous)."""
    t, _, origins, dirs = _predict(beams, nominal, target, x)
    measured = beams.range_m - x[len(PARAMETERS)]
    out = measured - t
    miss = ~np.isfinite(t)
    if miss.any():
        out[miss] = target.distance(origins[miss] + measured[miss, None] * dirs[miss],
                                    disk_radius_m=nominal.disk_radius_m, disk_thickness_m=nominal.disk_thickness_m)
    return out


def _jacobian(beams: _Beams, nominal: RigGeometry, target: CalibrationTarget, x: np.ndarray, free: np.ndarray
              ) -> np.ndarray:
    """(n, n_free) derivative of :func:`_residuals` by each free parameter in units of ``_SCALE``.

    The rays' own derivatives are taken by finite differences (cheap: no casting); the range
    along a ray to a surface moves as ``dt = -n . (do + t dd) / (n . d)`` (n the surface
    normal at the hit), so each step costs no ray casting. A beam that misses gets a zero row.
    """
    t, surface, origins, dirs = _predict(beams, nominal, target, x)
    hit = np.isfinite(t)
    normals = surface_normals(target, origins + np.where(hit, t, 0.0)[:, None] * dirs, surface,
                              disk_radius_m=nominal.disk_radius_m, disk_thickness_m=nominal.disk_thickness_m)
    with np.errstate(invalid="ignore", divide="ignore"):
        n_dot_d = np.einsum("ij,ij->i", normals, dirs)
    columns = []
    for k in np.nonzero(free)[0]:
        if k == len(PARAMETERS):  # the range offset: r = measured - offset - t
            columns.append(np.full(len(t), -_SCALE[k]))
            continue
        h = 1e-3
        step = np.zeros(len(x))
        step[k] = h * _SCALE[k]
        o_plus, d_plus = _rays(beams, nominal, x + step)
        o_minus, d_minus = _rays(beams, nominal, x - step)
        d_o, d_d = (o_plus - o_minus) / (2 * h), (d_plus - d_minus) / (2 * h)
        with np.errstate(invalid="ignore", divide="ignore"):
            dt = -np.einsum("ij,ij->i", normals, d_o + np.where(hit, t, 0.0)[:, None] * d_d) / n_dot_d
        columns.append(np.where(hit & np.isfinite(dt), -dt, 0.0))
    return np.column_stack(columns)


def _interior(beams: _Beams, nominal: RigGeometry, target: CalibrationTarget, x: np.ndarray, margin_rad: float
              ) -> np.ndarray:
    """(n,) bool: the beam's predicted hit, and hits moved by ``margin_rad`` in beam and table angle,
    lie on one smooth surface, met at less than the grazing limit."""
    t, surface, _, _ = _predict(beams, nominal, target, x)
    keep = np.isfinite(t)
    ends = []
    for shift in ({"d_beam_rad": margin_rad}, {"d_beam_rad": -margin_rad}, {"d_table_rad": margin_rad},
                  {"d_table_rad": -margin_rad}):
        t_shift, surface_shift, _, _ = _predict(beams, nominal, target, x, **shift)
        keep &= np.isfinite(t_shift) & (surface_shift == surface)
        ends.append(t_shift)
    with np.errstate(invalid="ignore"):
        # Range change across the beam's own fan: tan(incidence) = dr / (r da).
        tan_incidence = np.abs(ends[0] - ends[1]) / (2 * margin_rad * t)
    return keep & (tan_incidence < _MAX_TAN_INCIDENCE)


def _robust_sigma(r: np.ndarray) -> float:
    return 1.4826 * float(np.median(np.abs(r - np.median(r))))


def _search_encoder_offset(beams: _Beams, nominal: RigGeometry, target: CalibrationTarget, x: np.ndarray,
                           clip_m: float) -> float:
    """The encoder offset (degrees) whose residuals fit best, searched over a whole turn:
    only its basin matters, the joint fit refines it."""
    k = PARAMETERS.index("encoder_offset_deg")
    best = (np.inf, x[k])
    for step_deg, span_deg in ((2.0, 180.0), (0.25, 2.5)):
        centre = best[1]
        for offset in centre + np.arange(-span_deg, span_deg + step_deg / 2, step_deg):
            trial = x.copy()
            trial[k] = offset
            t = _predict(beams, nominal, target, trial)[0]
            r = np.where(np.isfinite(t), beams.range_m - t, clip_m)
            cost = float(np.sum(np.minimum(r * r, clip_m * clip_m)))
            if cost < best[0]:
                best = (cost, float(offset))
    return (best[1] + 180.0) % 360.0 - 180.0


def calibrate(raw: RawScan, *, nominal: RigGeometry = RigGeometry(), target: CalibrationTarget = CALIBRATION_TARGET,
              range_offset_m: float | None = 0.0, range_offset_std_m: float = 0.0, place_target: bool = True, max_points: int = 200_000,
              search_encoder: bool = True, seed: int = 0, model_std: Mapping[str, float] | None = MODEL_STD) -> Calibration:
    """Fits the rig geometry to a raw record of the calibration target.

    Args:
      raw: the raw record (simulated, or from a real rig's bag). Its line times,
        ranges, statuses, beam angles and encoder readings are used; a simulated
        record's ground truth is not.
      nominal: where to start, and the fixed geometry (disk size). Distance and
        height within a few centimetres, angles within a few degrees; its
        ``encoder_offset_deg`` is where the search for the encoder's zero starts.
      target: the target's sizes (as built and measured).
      range_offset_m: the LiDAR's known range offset on the target (measured minus
        true, metres; ``plantsim sensor fit`` measures it against a flat plate),
        subtracted from every range. None fits it as well: the target sees the
        LiDAR over too narrow a fan to tell a range offset from the distance well
        (``docs/calibration.md``), so the distance's uncertainty grows several-fold.
      range_offset_std_m: how well the range offset is known (1 sigma, metres): its
        effect on each parameter is added to the stated uncertainties (a told offset
        that is off by b moves the distance by about b).
      place_target: fit where the target stands on the disk (its centre's x and y);
        False takes it as centred on the axis exactly.
      max_points: beams used at most (a fixed random subset of those on the target).
      search_encoder: search the whole turn for the encoder's zero (False: start at
        ``nominal.encoder_offset_deg``, which must then be within a few degrees).
      seed: the subset's seed.
      model_std: the sensor's systematic share of each parameter's uncertainty (1 sigma,
        added in quadrature to the fit's statistical sigma of a fitted parameter), e.g.
        ``{"tilt_deg": 0.03}``; the default :data:`MODEL_STD` is empty: the simulated
        URG-04LX on the shipped target needs none. None or {} states the statistical
        sigma alone.

    Returns:
      The fitted geometry with its uncertainties.

    Raises:
      ValueError: too few returns near the target, or too few lines to see it
        from enough sides to fit the parameters.
    """
    from scipy.optimize import least_squares

    if max_points < 500:
        raise ValueError(f"max_points must be at least 500, got {max_points}")
    ok = (raw.status == BeamStatus.OK) & np.isfinite(raw.range_m)
    lines, beams_i = np.nonzero(ok)
    readings = raw.turntable_angle_rad[lines, beams_i] + raw.encoder_offset_rad
    n_lines = int(np.unique(lines).size)
    if n_lines < 24:
        raise ValueError(f"the record has {n_lines} lines with returns; calibration needs the target seen from all "
                         f"sides: scan a whole turn in steps of 15 degrees or less (1 degree is best)")
    # Candidates: returns within a generous cylinder around the target under the starting rig
    # (4 sigma of noise wider than the disk, so the final choice, made by prediction, is not cut).
    margin = 0.04
    p0 = base_to_turntable(points_base_from_ranges(raw.range_m[lines, beams_i], raw.beam_angle_rad[beams_i],
                                                   nominal.T_base_lidar()),
                           readings - math.radians(nominal.encoder_offset_deg))
    radius = np.hypot(p0[:, 0], p0[:, 1])
    near = (radius < nominal.disk_radius_m + margin) & (p0[:, 2] > -margin) & (p0[:, 2] < target.top_m + margin)
    above_disk = int((near & (p0[:, 2] > 0.01) & (radius < target.reach_m + 0.02)).sum())
    if above_disk < 500:
        raise ValueError(f"only {above_disk} returns lie near the calibration target under the starting rig "
                         f"geometry; scan the target (plant bundled = \"calibration-target\") and start from a rig "
                         f"within a few centimetres of the real one ([rig] in the configuration)")
    rng = np.random.default_rng(seed)
    sel = np.nonzero(near)[0]
    beams = _Beams(range_m=raw.range_m[lines[sel], beams_i[sel]].astype(np.float64),
                   beam_angle_rad=raw.beam_angle_rad[beams_i[sel]], reading_rad=readings[sel])

    # One random priority a beam, drawn once: a subset of n beams is the n of highest priority
    # among those allowed, so two rounds that allow the same beams fit the same beams.
    priority = rng.random(len(beams.range_m))

    def subset(mask: np.ndarray, n: int) -> _Beams:
        idx = np.nonzero(mask)[0]
        if len(idx) > n:
            idx = np.sort(idx[np.argpartition(priority[idx], n - 1)[:n]])
        return _Beams(beams.range_m[idx], beams.beam_angle_rad[idx], beams.reading_rad[idx])

    if range_offset_m is not None and not (isinstance(range_offset_m, (int, float)) and math.isfinite(range_offset_m)
                                           and abs(range_offset_m) < 0.1):
        raise ValueError(f"range_offset_m must be a number of metres within +-0.1 or None (fit it), "
                         f"got {range_offset_m!r}")
    if not (isinstance(range_offset_std_m, (int, float)) and 0 <= range_offset_std_m < 0.1):
        raise ValueError(f"range_offset_std_m must be a number of metres in [0, 0.1), got {range_offset_std_m!r}")
    x0 = np.array([getattr(nominal, k) for k in PARAMETERS]
                  + [0.0 if range_offset_m is None else float(range_offset_m), 0.0, 0.0], dtype=np.float64)
    free = np.array([True] * len(PARAMETERS) + [range_offset_m is None, place_target, place_target])
    x = x0.copy()
    if search_encoder:
        x[PARAMETERS.index("encoder_offset_deg")] = _search_encoder_offset(
            subset(np.ones(len(beams.range_m), bool), 2000), nominal, target, x, clip_m=0.03)
    lower = np.where(np.isfinite(_BOUNDS), (-_BOUNDS) / _SCALE, -np.inf)
    upper = np.where(np.isfinite(_BOUNDS), _BOUNDS / _SCALE, np.inf)
    step_rad = float(np.median(np.abs(np.diff(raw.beam_angle_rad)))) if raw.n_beams > 1 else 0.0
    # The beams are chosen by the geometry's prediction, so a choice made at a geometry that is
    # still off keeps beams that straddle an edge there, and those pull the fit towards the
    # geometry they were chosen at. The coarse rounds (a subset, wide margins) bring the geometry
    # near; the final margin's round is then repeated, choosing the beams again at each answer,
    # until the choice no longer changes (a fixed point: the beams chosen at the answer give the
    # answer). On the study's rigs the first final round alone left the encoder's zero up to
    # 0.43 degrees off where the fixed point is within 0.2 (docs/calibration.md).
    final_margin = max(math.radians(0.75), 2 * step_rad)
    rounds = ([(math.radians(3.0), 6000, False), (math.radians(1.5), 20000, False)]
              + [(final_margin, max_points, True)] * _MAX_FINAL_ROUNDS)
    previous = None
    for round_index, (margin_rad, n_use, final) in enumerate(rounds):
        inside = _interior(beams, nominal, target, x, margin_rad)
        if inside.sum() < 200:
            raise ValueError(f"only {int(inside.sum())} returns fall on the calibration target's surfaces; scan "
                             f"the target as plantsim.plant.target describes and start from a rig near the real one")
        if final and previous is not None and np.count_nonzero(inside != previous) <= _SETTLED_BEAMS * inside.size:
            break  # the same beams again: the same answer
        if final:
            previous = inside
        # The coarse rounds only bring the geometry near enough to choose the beams again: a subset will do.
        use = subset(inside, min(max_points, n_use))
        centre = x.copy()

        def fun(z_free, use=use, centre=centre):
            z = np.zeros(len(_ALL))
            z[free] = z_free
            return _residuals(use, nominal, target, centre + z * _SCALE)

        r0 = fun(np.zeros(int(free.sum())))
        scale = max(_robust_sigma(r0), 2e-4)
        shift = (centre - x0) / _SCALE
        def jac(z_free, use=use, centre=centre):
            z = np.zeros(len(_ALL))
            z[free] = z_free
            return _jacobian(use, nominal, target, centre + z * _SCALE, free)

        last = least_squares(fun, np.zeros(int(free.sum())), jac=jac, loss="cauchy", f_scale=2 * scale, x_scale=1.0,
                             bounds=((lower - shift)[free], (upper - shift)[free]), max_nfev=100 if final else 25,
                             ftol=1e-10 if final else 1e-8, xtol=1e-10 if final else 1e-8)
        x = centre.copy()
        x[free] += last.x * _SCALE[free]
        fit = last
        log.debug("calibration round %d: %d beams, margin %.2f deg, %s after %d evaluations, cost %.6g",
                  round_index, len(use.range_m), math.degrees(margin_rad), last.message, last.nfev, last.cost)
    else:
        log.info("calibration: the beams chosen still changed after %d final rounds; the last fit is reported",
                 _MAX_FINAL_ROUNDS)
    res = fit.fun
    sigma = max(_robust_sigma(res), 1e-9)
    kept = np.abs(res - np.median(res)) < 3 * sigma
    # least_squares's Jacobian is weighted by the loss (beams far out count less), as the fit
    # weighted them; it gives larger, more honest sigmas than the plain one (docs/calibration.md).
    J = fit.jac[kept]
    n_kept = int(kept.sum())
    dof = max(n_kept - int(free.sum()), 1)
    # Fixed parameters: no uncertainty from this fit (zero), no correlation (NaN).
    std = np.zeros(len(_ALL))
    correlation = np.full((len(_ALL), len(_ALL)), np.nan)
    try:
        # One residual variance for all beams. (The heteroscedasticity-consistent sandwich form
        # gives 15 % smaller sigmas here: the oblique faces are not noisier than the rest.)
        cov_z = np.linalg.inv(J.T @ J) * float(np.sum(res[kept] ** 2) / dof)
        std_z = np.sqrt(np.clip(np.diag(cov_z), 0, None))
        with np.errstate(invalid="ignore", divide="ignore"):
            correlation[np.ix_(free, free)] = cov_z / np.outer(std_z, std_z)
        if range_offset_m is not None and range_offset_std_m > 0:
            # A told offset off by db shifts the fit by dz = (J^T J)^-1 J^T dr/db db, with dr/db = -1.
            dz_db = np.linalg.solve(J.T @ J, J.T @ -np.ones(len(J)))
            cov_z = cov_z + np.outer(dz_db, dz_db) * range_offset_std_m ** 2
            std_z = np.sqrt(np.clip(np.diag(cov_z), 0, None))
            with np.errstate(invalid="ignore", divide="ignore"):
                correlation[np.ix_(free, free)] = cov_z / np.outer(std_z, std_z)
        std[free] = std_z * _SCALE[free]
    except np.linalg.LinAlgError:
        std[free] = np.inf
    x[PARAMETERS.index("encoder_offset_deg")] = (x[PARAMETERS.index("encoder_offset_deg")] + 180.0) % 360.0 - 180.0
    std_fit = {k: float(v) for k, v in zip(_ALL, std)}
    floor = dict(model_std or {})
    unknown = set(floor) - set(_ALL)
    if unknown:
        raise ValueError(f"model_std names no calibration parameter: {sorted(unknown)}; use {', '.join(_ALL)}")
    std_by_name = {k: float(np.hypot(v, floor.get(k, 0.0))) if free[i] else v
                   for i, (k, v) in enumerate(std_fit.items())}
    return Calibration(rig=_rig_with(nominal, x), std=std_by_name, std_fit=std_fit,
                       nuisance={k: float(v) for k, v in zip(NUISANCE, x[len(PARAMETERS):])},
                       observable={k: bool(std_by_name[k] < OBSERVABLE_STD[k]) for k in _ALL},
                       correlation=correlation,
                       rms_m=float(np.sqrt(np.mean(res[kept] ** 2))) if kept.any() else float("nan"),
                       n_points=len(res), n_kept=int(kept.sum()), start=nominal)


def rig_toml(calibration: Calibration, *, source: str = "") -> str:
    """A ``[rig]`` TOML section with the fitted geometry, the uncertainties as comments."""
    rig = calibration.rig

    def shown(name: str, value: float) -> str:
        return f"{value * 1e3:.3f} mm" if name.endswith("_m") else f"{value:.3f} deg"

    lines = ["# Rig geometry fitted by `plantsim calibrate`" + (f" from {source}" if source else ""),
             f"# {calibration.n_kept:,} of {calibration.n_points:,} returns on the target; RMS range residual "
             f"{calibration.rms_m * 1e3:.3f} mm. Uncertainties: one standard deviation of the fit.",
             "# Not rig geometry, fitted alongside: " + ", ".join(
                 f"{k} {shown(k, v)} " + (f"+- {shown(k, calibration.std[k])}" if calibration.std[k] > 0 else "(given)")
                 for k, v in calibration.nuisance.items()),
             "[rig]"]
    for name in PARAMETERS:
        flag = "" if calibration.observable[name] else "  (NOT pinned by this scan)"
        lines.append(f"{name} = {getattr(rig, name)!r}  # +- {shown(name, calibration.std[name])}{flag}")
    for name in ("disk_radius_m", "disk_thickness_m", "pedestal_height_m"):
        lines.append(f"{name} = {getattr(rig, name)!r}")
    return "\n".join(lines) + "\n"
