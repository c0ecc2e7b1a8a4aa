"""A LiDAR that behaves like the real one: footprint, noise, intensity, dropouts.

The sensor's own numbers (divergence, accuracy, resolution, detection
threshold) are in its :class:`plantsim.sensor.LidarSpec` preset; this module
holds what the simulation does with them (:class:`SensorModel`, TOML section
``[sensor_model]``) and the scan that applies them
(:func:`realistic_step_and_shoot`). Each effect can be switched off; the
run's ``ideal`` flag bypasses this module altogether (perfect geometry).

Per beam, in order:

1. Footprint: sub-rays (:mod:`plantsim.beam`) are cast with surface normals;
   their returns combine into one range (power-weighted: mixed pixels), one
   received power and one mean incidence.
2. Dropouts: no sub-ray echo is NO_ECHO; a received power below the sensor's
   threshold is LOW_INTENSITY (URG error codes 1-2); a footprint spread over
   more than ``edge_range_spread_m`` is EDGE (URG error code 7).
3. Range noise: Gaussian, sigma(r, theta) from :func:`range_sigma`.
4. Quantisation to the sensor's range resolution.
5. Range limits on the measured range: below ``range_min_m`` is TOO_NEAR,
   beyond ``range_max_m`` NO_ECHO. Never a clamped point.

Intensity (received power) is kept for every beam with an echo.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import os

import mujoco
import mujoco.batch
import numpy as np

from plantsim.beam import (SubrayPattern, coplanar_probes, combine_footprint, subray_pattern,
                           subrays_lidar)
from plantsim.scan import (AXIS_TRAP_OFFSET_M, Progress, RawScan, StepScan, kinematic_raw_scan,
                           ray_origins_dirs_base)
from plantsim.scene import LIDAR_GEOMGROUP, HitClass, Scene
from plantsim.sensor import BeamStatus, LidarSpec

log = logging.getLogger(__name__)

# Beyond 80 degrees of incidence the noise law is held constant (at most
# 5.8 times the head-on sigma for gain 1); most such grazing returns are
# dropped by the power threshold anyway.
COS_INCIDENCE_FLOOR = math.cos(math.radians(80.0))


@dataclasses.dataclass(frozen=True, kw_only=True)
class SensorModel:
    """Which sensor imperfections a (non-ideal) scan simulates, and the scene's reflectances.

    TOML section ``[sensor_model]``.

    Attributes:
      range_noise: add Gaussian range noise (:func:`range_sigma`).
      quantise: round ranges to the sensor's ``range_resolution_m``.
      footprint_rings: rings of sub-rays across the beam footprint
        (0: one ray, 1: 7, 2: 19, 3: 37); the quality setting of mixed pixels.
      adaptive_footprint: cast the full footprint only where its probe rays
        (axis + 4 outer) do not land on one flat surface; elsewhere the axis
        ray stands for the whole footprint. False casts every sub-ray of every
        beam (the reference; several times slower).
      flat_tolerance_m: how far a probe's hit may lie off the axis hit's
        tangent plane for the footprint to count as flat, metres.
      intensity: record the received power as intensity.
      dropouts: drop weak returns (LOW_INTENSITY) and spread footprints (EDGE).
      reflectance_plant: Lambertian reflectance of the plant at the laser's
        wavelength. 0.5: green leaves reflect about half of near-infrared
        light (the NIR plateau, 750-1300 nm; Jacquemoud and Baret 1990, PROSPECT).
      reflectance_turntable: of the turntable disk (0.5: assumed grey plastic).
      reflectance_rig: of the bench, post and pedestal (0.2: assumed dark
        painted or anodised metal).
      saturation_range_m: the receiver saturates (intensity 1) for a white
        target seen head-on nearer than this; intensity is
        ``min(1, power * saturation_range_m^2)``.
    """

    range_noise: bool = True
    quantise: bool = True
    footprint_rings: int = 2
    adaptive_footprint: bool = True
    flat_tolerance_m: float = 0.002
    intensity: bool = True
    dropouts: bool = True
    reflectance_plant: float = 0.5
    reflectance_turntable: float = 0.5
    reflectance_rig: float = 0.2
    saturation_range_m: float = 0.1

    def __post_init__(self):
        for field in ("range_noise", "quantise", "adaptive_footprint", "intensity", "dropouts"):
            if not isinstance(getattr(self, field), bool):
                raise ValueError(f"{field} must be true or false, got {getattr(self, field)!r}")
        rings = self.footprint_rings
        if isinstance(rings, bool) or not isinstance(rings, int) or not 0 <= rings <= 10:
            raise ValueError(f"footprint_rings must be an integer from 0 to 10, got {rings!r}")
        for field in ("reflectance_plant", "reflectance_turntable", "reflectance_rig"):
            value = getattr(self, field)
            if (isinstance(value, bool) or not isinstance(value, (int, float))
                    or not 0.0 <= value <= 1.0):
                raise ValueError(f"{field} must be a number in [0, 1], got {value!r}")
        for field in ("flat_tolerance_m", "saturation_range_m"):
            value = getattr(self, field)
            if (isinstance(value, bool) or not isinstance(value, (int, float))
                    or not math.isfinite(value) or value <= 0):
                raise ValueError(f"{field} must be a finite number > 0, got {value!r}")

    @classmethod
    def off(cls) -> "SensorModel":
        """Every effect off: one ray per beam, exact ranges, no intensity."""
        return cls(range_noise=False, quantise=False, footprint_rings=0, intensity=False,
                   dropouts=False)

    def reflectance_by_class(self) -> np.ndarray:
        """(len(HitClass),) float64 reflectance indexed by :class:`HitClass` (NONE: 0)."""
        table = np.zeros(len(HitClass))
        table[HitClass.PLANT] = self.reflectance_plant
        table[HitClass.TURNTABLE] = self.reflectance_turntable
        table[HitClass.RIG] = self.reflectance_rig
        return table


def range_sigma(range_m: np.ndarray, cos_incidence: np.ndarray, lidar: LidarSpec) -> np.ndarray:
    """Standard deviation of the range noise.

    sigma = max(range_sigma_m, range_sigma_rel * r) * (1 + gain * (1/cos(theta) - 1))

    The first factor is the datasheet's accuracy bands (URG-04LX: +-30 mm to
    1 m, 3 % of range beyond); the second makes the noise grow as the return
    weakens with incidence (1/cos law at gain 1; Soudarissanane et al. 2009).
    cos(theta) is floored at :data:`COS_INCIDENCE_FLOOR`.

    Args:
      range_m: (...) float64 metres.
      cos_incidence: (...) float64 in [0, 1].
      lidar: the sensor's noise parameters.

    Returns:
      (...) float64 metres.
    """
    r = np.asarray(range_m, dtype=np.float64)
    cos = np.maximum(np.asarray(cos_incidence, dtype=np.float64), COS_INCIDENCE_FLOOR)
    base = np.maximum(lidar.range_sigma_m, lidar.range_sigma_rel * r)
    return base * (1.0 + lidar.range_sigma_incidence_gain * (1.0 / cos - 1.0))


def intensity_from_power(power: np.ndarray, model: SensorModel) -> np.ndarray:
    """Received power (m^-2) to intensity in [0, 1]; 1 is receiver saturation."""
    return np.minimum(1.0, power * model.saturation_range_m ** 2)


def apply_sensor(range_m: np.ndarray, power: np.ndarray, cos_incidence: np.ndarray,
                 spread_m: np.ndarray, lidar: LidarSpec, model: SensorModel,
                 rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Dropouts, noise, quantisation and range limits on combined footprint returns.

    Args:
      range_m: (n_lines, n_beams) float64 metres, combined true range, NaN: no echo.
      power: (n_lines, n_beams) float64 received power, m^-2.
      cos_incidence: (n_lines, n_beams) float64, mean cos(incidence).
      spread_m: (n_lines, n_beams) float64, footprint range spread, metres.
      lidar: the sensor.
      model: which effects.
      rng: the run's generator; with range noise on, exactly one
        ``standard_normal((n_lines, n_beams))`` draw is taken from it.

    Returns:
      range_m (NaN unless OK), status uint8 :class:`BeamStatus`, and intensity
      (float32 in [0, 1], NaN without echo) or None when intensity is off.
    """
    echo = np.isfinite(range_m)
    status = np.where(echo, BeamStatus.OK, BeamStatus.NO_ECHO).astype(np.uint8)
    if model.dropouts:
        if lidar.detection_range_white_m is not None:
            # The weakest return the sensor ranges on: a white Lambertian target
            # head-on at detection_range_white_m, P = 1 / d^2.
            weak = echo & (power < 1.0 / lidar.detection_range_white_m ** 2)
            status[weak] = BeamStatus.LOW_INTENSITY
        if lidar.edge_range_spread_m is not None:
            status[(status == BeamStatus.OK) & (spread_m > lidar.edge_range_spread_m)] = BeamStatus.EDGE
    measured = np.where(echo, range_m, 0.0)
    if model.range_noise:
        z = rng.standard_normal(measured.shape)
        measured = measured + range_sigma(measured, np.where(echo, cos_incidence, 1.0), lidar) * z
    if model.quantise and lidar.range_resolution_m > 0:
        measured = np.round(measured / lidar.range_resolution_m) * lidar.range_resolution_m
    ok = status == BeamStatus.OK
    status[ok & (measured < lidar.range_min_m)] = BeamStatus.TOO_NEAR
    status[ok & (measured > lidar.range_max_m)] = BeamStatus.NO_ECHO
    range_out = np.where(status == BeamStatus.OK, measured, np.nan)
    intensity = None
    if model.intensity:
        intensity = np.where(echo, intensity_from_power(power, model), np.nan).astype(np.float32)
    return range_out, status, intensity


class FootprintCaster:
    """Casts every beam's footprint with ``mujoco.batch``, one simulation per line.

    Per line and chunk of lines: first the probe sub-rays of every beam (one
    batch call of n_beams x n_probe rays, with normals), then, for the beams
    whose probes do not land on one flat surface, the remaining sub-rays (one
    batch call, padded to the line with most such beams). With
    ``adaptive=False`` every sub-ray of every beam is cast.
    """

    def __init__(self, scene: Scene, lidar: LidarSpec, model: SensorModel, *,
                 nthread: int | None = None, max_lines: int = 4096):
        self.scene = scene
        self.lidar = lidar
        self.model = model
        self.pattern: SubrayPattern = subray_pattern(model.footprint_rings)
        self.beam_angles_rad = lidar.beam_angles_rad()
        origins_lidar, dirs_lidar = subrays_lidar(
            self.beam_angles_rad, self.pattern, divergence_rad=lidar.beam_divergence_rad,
            exit_diameter_m=lidar.beam_exit_diameter_m)
        T = scene.T_base_lidar
        R = T[:3, :3]
        self.origins_base = origins_lidar @ R.T + T[:3, 3] + AXIS_TRAP_OFFSET_M * R[:, 2]
        self.dirs_base = dirs_lidar @ R.T
        # The axis rays exactly as the ideal scanner casts them.
        axis_origin, axis_dirs = ray_origins_dirs_base(T, self.beam_angles_rad)
        self.origins_base[:, 0] = axis_origin
        self.dirs_base[:, 0] = axis_dirs
        self.adaptive = model.adaptive_footprint and self.pattern.n_subrays > 1
        self.reflectance = model.reflectance_by_class()
        self.nthread = nthread or max(1, os.cpu_count() or 1)
        self._max_lines = max_lines
        self._batch = None
        self._nsim = 0
        self.n_refined = 0  # beams whose whole footprint was cast, last cast()
        self.n_rays = 0  # rays cast (padding included), last cast()
        stat = scene.model.stat
        self._pad_origin = np.asarray(stat.center) + (0.0, 0.0, 10.0 * max(stat.extent, 1.0))

    def _ensure_batch(self, n: int):
        if self._batch is None or self._nsim < n:
            self._nsim = max(n, 1)
            self._batch = mujoco.batch.Batch(self.scene.model, nsim=self._nsim, nthread=self.nthread)
        return self._batch

    def _ray(self, batch, pnt, vec, ids):
        self.n_rays += len(ids) * (np.shape(vec)[-2])
        return batch.ray(pnt, vec, geomgroup=LIDAR_GEOMGROUP, flg_static=True,
                         bodyexclude=self.scene.lidar_body_id, ids=ids, normal=True)

    def _combine(self, dist, geom, normal, dirs, weights):
        cos = np.abs(np.einsum("...k,...k->...", normal, dirs))
        refl = self.reflectance[self.scene.geom_class[geom]]
        ret = combine_footprint(dist, cos, refl, weights, range_max_m=self.lidar.range_max_m)
        dom = np.maximum(ret.dominant, 0)
        geom_dom = np.where(ret.dominant >= 0,
                            np.take_along_axis(geom, dom[..., None], axis=-1)[..., 0], -1)
        return ret, geom_dom

    def cast(self, qpos_turntable_rad: np.ndarray, *, progress: Progress | None = None,
             chunk_lines: int = 64) -> dict[str, np.ndarray]:
        """Combined footprint returns per beam, one line per turntable angle.

        Args:
          qpos_turntable_rad: (n_lines,) float64, the true hinge angle per line.
          progress: called with (lines done, lines total) after each chunk.
          chunk_lines: lines per batch call.

        Returns:
          dict of (n_lines, n_beams) arrays: ``range_m`` (NaN: no echo),
          ``power``, ``cos_incidence``, ``spread_m`` (float64) and ``geom_id``
          (int32, the geom returning most power, -1: none).
        """
        q = np.asarray(qpos_turntable_rad, dtype=np.float64).reshape(-1)
        n, n_beams = len(q), len(self.beam_angles_rad)
        out = {k: np.full((n, n_beams), np.nan) for k in ("range_m", "power", "cos_incidence",
                                                         "spread_m")}
        out["geom_id"] = np.full((n, n_beams), -1, dtype=np.int32)
        pattern = self.pattern
        probe = pattern.probe if self.adaptive else np.arange(pattern.n_subrays)
        rest = np.setdiff1d(np.arange(pattern.n_subrays), probe)
        probe_o = self.origins_base[:, probe].reshape(-1, 3)
        probe_d = self.dirs_base[:, probe].reshape(-1, 3)
        adr = self.scene.turntable_qpos_adr
        self.n_refined = 0
        self.n_rays = 0
        for start in range(0, n, self._max_lines):
            block = q[start:start + self._max_lines]
            batch = self._ensure_batch(len(block))
            batch.bind("qpos")[: len(block), adr] = block
            for lo in range(0, len(block), chunk_lines):
                ids = np.arange(lo, min(lo + chunk_lines, len(block)))
                rows = start + ids
                d, g, nrm = self._ray(batch, probe_o, probe_d, ids)
                c = len(ids)
                d = d.reshape(c, n_beams, len(probe))
                g = g.reshape(c, n_beams, len(probe))
                nrm = nrm.reshape(c, n_beams, len(probe), 3)
                if self.adaptive:
                    hit = (self.origins_base[None, :, probe]
                           + np.maximum(d, 0)[..., None] * self.dirs_base[None, :, probe])
                    refine = ~coplanar_probes(hit, nrm, g, tolerance_m=self.model.flat_tolerance_m)
                    # Flat footprints: the axis ray stands for the whole footprint.
                    ret, geom_dom = self._combine(d[:, :, :1], g[:, :, :1], nrm[:, :, :1],
                                                  self.dirs_base[None, :, :1], np.ones(1))
                else:
                    refine = np.zeros((c, n_beams), dtype=bool)
                    ret, geom_dom = self._combine(d, g, nrm, self.dirs_base[None],
                                                  pattern.weights)
                self._store(out, rows, slice(None), ret, geom_dom)
                if refine.any():
                    self._refine(out, batch, ids, rows, refine, d, g, nrm, probe, rest)
                if progress is not None:
                    progress(int(rows[-1]) + 1, n)
        return out

    @staticmethod
    def _store(out, rows, beams, ret, geom_dom):
        out["range_m"][rows, beams] = ret.range_m
        out["power"][rows, beams] = ret.power
        out["cos_incidence"][rows, beams] = ret.cos_incidence
        out["spread_m"][rows, beams] = ret.spread_m
        out["geom_id"][rows, beams] = geom_dom

    def _refine(self, out, batch, ids, rows, refine, d, g, nrm, probe, rest):
        """Casts the non-probe sub-rays of the flagged beams and combines all."""
        pattern = self.pattern
        line_of, beam_of = np.nonzero(refine)
        self.n_refined += len(line_of)
        counts = refine.sum(axis=1)
        m = int(counts.max())
        n_rest = len(rest)
        # Each line's flagged beams first, then padding: rays from far above
        # the scene going up, which miss every bounding box at once.
        starts = np.cumsum(counts) - counts
        pos = np.arange(len(line_of)) - np.repeat(starts, counts)
        pnt = np.empty((len(ids), m, n_rest, 3))
        vec = np.empty((len(ids), m, n_rest, 3))
        pnt[:] = self._pad_origin
        vec[:] = (0.0, 0.0, 1.0)
        pnt[line_of, pos] = self.origins_base[beam_of][:, rest]
        vec[line_of, pos] = self.dirs_base[beam_of][:, rest]
        pnt = pnt.reshape(len(ids), m * n_rest, 3)
        vec = vec.reshape(len(ids), m * n_rest, 3)
        d2, g2, n2 = self._ray(batch, pnt, vec, ids)
        d2 = d2.reshape(len(ids), m, n_rest)[line_of, pos]
        g2 = g2.reshape(len(ids), m, n_rest)[line_of, pos]
        n2 = n2.reshape(len(ids), m, n_rest, 3)[line_of, pos]
        k = len(line_of)
        dist = np.empty((k, pattern.n_subrays))
        geom = np.empty((k, pattern.n_subrays), dtype=np.int32)
        normal = np.empty((k, pattern.n_subrays, 3))
        dist[:, probe], geom[:, probe], normal[:, probe] = (d[line_of, beam_of], g[line_of, beam_of],
                                                            nrm[line_of, beam_of])
        dist[:, rest], geom[:, rest], normal[:, rest] = d2, g2, n2
        ret, geom_dom = self._combine(dist, geom, normal, self.dirs_base[beam_of], pattern.weights)
        self._store(out, rows[line_of], beam_of, ret, geom_dom)


def realistic_step_and_shoot(scene: Scene, lidar: LidarSpec, schedule: StepScan,
                             model: SensorModel, *, rng: np.random.Generator,
                             caster: FootprintCaster | None = None,
                             progress: Progress | None = None) -> RawScan:
    """A kinematic step-and-shoot scan through the sensor model.

    Like :func:`plantsim.scan.step_and_shoot` (the table is exactly at each
    commanded angle for the whole line), but each beam is a sampled footprint
    and its return goes through :func:`apply_sensor`.

    Args:
      scene: a compiled scene.
      lidar: the sensor and its noise parameters.
      schedule: angles and timing.
      model: which effects, and the reflectances.
      rng: the run's one generator.
      caster: a :class:`FootprintCaster` to reuse (for this scene, sensor and model).
      progress: called with (lines done, lines total).

    Returns:
      The :class:`RawScan`, with ``intensity`` when the model records it.
    """
    if schedule.step_time_s < lidar.scan_period_s:
        raise ValueError(
            f"step_time_s ({schedule.step_time_s} s) must be at least the sensor's scan period "
            f"({lidar.scan_period_s} s): one line must fit in one step")
    caster = caster or FootprintCaster(scene, lidar, model)
    angles = schedule.angles_rad()
    fp = caster.cast(angles, progress=progress)
    log.debug("footprint: %d of %d beams refined with %d sub-rays", caster.n_refined,
              fp["geom_id"].size, caster.pattern.n_subrays)
    range_m, status, intensity = apply_sensor(fp["range_m"], fp["power"], fp["cos_incidence"],
                                              fp["spread_m"], lidar, model, rng)
    too_near = int((status == BeamStatus.TOO_NEAR).sum())
    if too_near > (status == BeamStatus.OK).sum():
        log.warning("%d beams returned nearer than %s's range_min_m (%g m), more than gave a "
                    "range: move the sensor back ([rig] lidar_distance_m = %g m now)", too_near,
                    lidar.name, lidar.range_min_m, scene.rig.lidar_distance_m)
    return kinematic_raw_scan(scene, lidar, schedule, range_m=range_m, status=status,
                              geom_id=fp["geom_id"], intensity=intensity)
