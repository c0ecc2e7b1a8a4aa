"""The simulated LiDAR: rays cast in the MuJoCo scene, then the sensor model.

:class:`SimulatedLidar` is a line source of the scan pipeline. Given the true
turntable angle of every beam (one per line in a step scan, one per beam when
the table turns during the line), it returns what the sensor reports: ranges,
statuses, intensities, and the ground truth of what each beam hit.

- ideal sensor (``model`` None): one geometric ray per beam, its exact first
  hit, the range limits, nothing else;
- realistic sensor: every beam a footprint of sub-rays (adaptive: only beams
  whose probe sub-rays do not land on one flat surface are cast in full), the
  returns combined as a phase-measuring sensor does, then dropouts, noise,
  quantisation and intensity (:func:`plantsim.sensor.model.apply_sensor`).

Ranges come out as float32 values (what a ``sensor_msgs/LaserScan`` carries),
so a scan's raw record and its ROS 2 bag hold the same numbers.
"""

from __future__ import annotations

import logging
import time
from typing import NamedTuple

import numpy as np

from plantsim.rig.geometry import beam_dirs_lidar
from plantsim.rig.scene import Scene
from plantsim.sensor import casting
from plantsim.sensor.casting import Backend, Caster, Progress, gate_ranges, take_rows
from plantsim.sensor.footprint import (FootprintReturn, coplanar_probes, combine_footprint, jitter_subrays,
                                      subray_pattern, subrays_lidar)
from plantsim.sensor.model import SensorModel, apply_sensor
from plantsim.sensor.spec import BeamStatus, LidarSpec

log = logging.getLogger(__name__)

# Jittered footprint patterns per beam (see SimulatedLidar): 16 x 19 sub-ray positions a beam.
FOOTPRINT_VARIANTS = 16
_VARIANT_SEED = 20261122


class Lines(NamedTuple):
    """What the sensor reported for some lines; arrays (n_lines, n_beams).

    range_m float64 (float32 values; NaN unless OK), status uint8 BeamStatus,
    intensity float32 or None, hit_class uint8 HitClass, geom_id int32.
    """

    range_m: np.ndarray
    status: np.ndarray
    intensity: np.ndarray | None
    hit_class: np.ndarray
    geom_id: np.ndarray


def as_float32_ranges(range_m: np.ndarray) -> np.ndarray:
    """Ranges rounded to float32, as a LaserScan carries them (float64 array)."""
    return np.asarray(range_m, dtype=np.float32).astype(np.float64)


class SimulatedLidar:
    """A simulated 2D LiDAR in a scan scene.

    Args:
      scene: the compiled scene (the sensor's pose is ``scene.T_base_lidar``).
      lidar: the sensor.
      beam_angles_rad: (n_beams,) the beam angles to cast (the raw record's grid).
      model: the sensor model, or None for the ideal sensor.
      backend: ray-casting backend (default MuJoCo's).
      nthread: casting threads of the default backend.
    """

    kind = "simulated"

    def __init__(self, scene: Scene, lidar: LidarSpec, beam_angles_rad: np.ndarray, *,
                 model: SensorModel | None = None, backend: Backend | None = None,
                 nthread: int | None = None):
        self.scene = scene
        self.lidar = lidar
        self.model = model
        self.beam_angles_rad = np.asarray(beam_angles_rad, dtype=np.float64)
        T = scene.T_base_lidar
        R = T[:3, :3]
        origin = T[:3, 3] + casting.AXIS_TRAP_OFFSET_M * R[:, 2]
        n_beams = len(self.beam_angles_rad)
        if model is None:
            self.n_sub = 1
            origins = np.broadcast_to(origin, (n_beams, 3))
            dirs = beam_dirs_lidar(self.beam_angles_rad) @ R.T
        else:
            self.pattern = subray_pattern(model.footprint_rings)
            self.n_sub = self.pattern.n_subrays
            # Footprints are sampled by stratified jitter (plantsim.sensor.footprint.jitter_subrays)
            # so that ranges between two surfaces form a continuum: FOOTPRINT_VARIANTS jittered
            # patterns per beam are drawn once (a fixed generator: the same rays every run),
            # and each beam of each line uses one of them, chosen with the run's generator.
            self.n_variants = FOOTPRINT_VARIANTS if self.n_sub > 1 else 1
            if self.n_variants > 1:
                offsets, weights = jitter_subrays(self.pattern, np.random.default_rng(_VARIANT_SEED),
                                                  (self.n_variants, n_beams))
            else:
                offsets, weights = None, np.broadcast_to(self.pattern.weights, (1, n_beams, self.n_sub))
            self.weights = np.asarray(weights)  # (n_variants, n_beams, n_sub)
            origins_lidar, dirs_lidar = subrays_lidar(
                self.beam_angles_rad, self.pattern, divergence_rad=lidar.beam_divergence_rad,
                exit_diameter_m=lidar.beam_exit_diameter_m, offsets=offsets)
            origins_lidar = np.broadcast_to(origins_lidar, (self.n_variants, n_beams, self.n_sub, 3))
            dirs_lidar = np.broadcast_to(dirs_lidar, (self.n_variants, n_beams, self.n_sub, 3))
            origins = (origins_lidar @ R.T + origin).reshape(-1, 3)
            dirs = (dirs_lidar @ R.T).reshape(-1, 3)
            if self.n_variants == 1:
                # The axis sub-ray exactly as the ideal sensor casts it.
                origins[:: self.n_sub] = origin
                dirs[:: self.n_sub] = beam_dirs_lidar(self.beam_angles_rad) @ R.T
            self.adaptive = model.adaptive_footprint and self.n_sub > 1
            self.reflectance = model.reflectance_by_class()
        self.caster = Caster(scene, origins, dirs, backend=backend, nthread=nthread)
        self.n_refined = 0
        self.n_beams_taken = 0
        self.n_subrays_probe = 0  # footprint sub-rays cast as probes (every sub-ray when not adaptive)
        self.n_subrays_refine = 0  # the other sub-rays of the beams whose probes were not flat
        self.n_beams_refined = 0
        self.lines_s = 0.0  # wall time in cast_lines, s (casting included)
        self.sensor_model_s = 0.0  # wall time of the range/intensity/noise model, s

    @property
    def ideal(self) -> bool:
        return self.model is None

    def describe(self) -> dict:
        """What this sensor simulates, for the sidecar."""
        out = {"kind": "simulated", "model": self.lidar.name,
               "sensor": "ideal" if self.ideal else "realistic",
               "ray_caster": self.caster.backend.name}
        detail = getattr(self.caster.backend, "detail", None)
        if detail:
            out["ray_caster_detail"] = detail
        if self.ideal:
            out["effects"] = "none: one geometric ray per beam, exact first hit, range limits"
        else:
            m = self.model
            out["effects"] = {
                "footprint_subrays": self.n_sub, "adaptive_footprint": bool(self.adaptive),
                "footprint_patterns": self.n_variants,
                "systematic_error": m.systematic_error,
                "range_noise": m.range_noise, "quantise": m.quantise, "intensity": m.intensity,
                "dropouts": m.dropouts}
        out["work"] = self.work()
        return out

    def work(self) -> dict:
        """What the casting cost so far: rays cast and wall time per phase (for the sidecar).

        ``rig_cast_once``: the whole ray table (every footprint sub-ray of every
        pattern) against the fixed rig, once; ``turning_cast``: rays cast against the
        turning parts (one per beam and line when ideal, the footprint's sub-rays
        when realistic), of which ``culled`` could not reach them at any angle and
        were resolved by a bounding-cylinder test without reaching the backend;
        ``sensor_model``: the range/intensity/noise model;
        ``footprint_and_bookkeeping``: the rest of the line source's time
        (rotating rays, combining sub-rays, merging with the rig's hits); for the
        realistic sensor also its ``subrays`` (``probe_rays`` cast for every beam plus
        ``refine_rays`` for the ``beams_refined`` whose probes were not flat; they are
        the turning cast's rays), and ``sensor_model`` its ``beams`` and ``beams_per_s``.
        """
        c = self.caster
        other_s = max(self.lines_s - c.cast_turning_s - self.sensor_model_s, 0.0)

        def phase(rays, seconds):
            # rays/s from the seconds as written, so the two agree however short the phase.
            out = {"rays": int(rays), "s": round(seconds, 9)}
            if rays and out["s"] > 0:
                out["rays_per_s"] = round(rays / out["s"])
            return out

        def per_beam(seconds):
            out = {"beams": int(self.n_beams_taken), "s": round(seconds, 9)}
            if self.n_beams_taken and out["s"] > 0:
                out["beams_per_s"] = round(self.n_beams_taken / out["s"])
            return out

        out = {"beams": int(self.n_beams_taken),
               "rig_cast_once": phase(c.n_rays_fixed, c.cast_fixed_s),
               "turning_cast": {**phase(c.n_rays_cast, c.cast_turning_s), "culled": int(c.n_rays_culled)},
               "sensor_model": {"s": round(self.sensor_model_s, 9)},
               "footprint_and_bookkeeping": {"s": round(other_s, 9)}}
        if not self.ideal:
            out["sensor_model"] = per_beam(self.sensor_model_s)
            subrays = self.n_subrays_probe + self.n_subrays_refine
            out["footprint_and_bookkeeping"] = {
                **phase(subrays, other_s), "subrays_per_beam": self.n_sub,
                "probe_rays": int(self.n_subrays_probe), "refine_rays": int(self.n_subrays_refine),
                "beams_refined": int(self.n_beams_refined)}
            out["footprint_and_bookkeeping"]["subrays"] = out["footprint_and_bookkeeping"].pop("rays")
        return out

    def cast_lines(self, table_rad: np.ndarray, rng: np.random.Generator, *,
                   beam_time_s: np.ndarray | None = None, progress: Progress | None = None) -> Lines:
        """The sensor's report for lines cast at true turntable angles.

        Args:
          table_rad: (n_lines,) one angle per line (the table at rest), or
            (n_lines, n_beams) one per beam, float64 radians.
          rng: the run's generator (the sensor model's only source of randomness).
          beam_time_s: (n_lines, n_beams) float64, each beam's time since the
            scan's start (the sensor's warm-up drift); None: all at the start.
          progress: called with (lines done, lines total).
        """
        t_start = time.perf_counter()
        theta = np.asarray(table_rad, dtype=np.float64)
        n_lines, n_beams = len(theta), len(self.beam_angles_rad)
        self.n_beams_taken += n_lines * n_beams
        if self.ideal:
            ids = np.broadcast_to(np.arange(n_beams), (n_lines, n_beams))
            hits = self.caster.cast(ids, theta, progress=progress)
            range_m, status = gate_ranges(hits.dist_m, self.lidar)
            geom = hits.geom_id
            intensity = None
        else:
            fp, geom = self._footprints(theta, rng, progress)
            t = time.perf_counter()
            range_m, status, intensity = apply_sensor(fp.range_m, fp.power, fp.cos_incidence,
                                                      fp.spread_m, self.lidar, self.model, rng,
                                                      hit_class=self.scene.geom_class[geom], line_time_s=beam_time_s)
            self.sensor_model_s += time.perf_counter() - t
            too_near = int((status == BeamStatus.TOO_NEAR).sum())
            if too_near > (status == BeamStatus.OK).sum():
                log.warning("%d beams returned nearer than %s's range_min_m (%g m), more than gave a "
                            "range: move the sensor back ([rig] lidar_distance_m = %g m now)", too_near,
                            self.lidar.name, self.lidar.range_min_m, self.scene.rig.lidar_distance_m)
        lines = Lines(range_m=as_float32_ranges(range_m), status=status, intensity=intensity,
                      hit_class=self.scene.geom_class[geom], geom_id=geom)
        self.lines_s += time.perf_counter() - t_start
        return lines

    # --- the footprint --------------------------------------------------------

    def _combine(self, dist, geom, normal, dirs, weights):
        cos = np.abs(normal[..., 0] * dirs[..., 0] + normal[..., 1] * dirs[..., 1] + normal[..., 2] * dirs[..., 2])
        refl = self.reflectance[self.scene.geom_class[geom]]
        ret = combine_footprint(dist, cos, refl, weights, range_max_m=self.lidar.range_max_m)
        dom = np.maximum(ret.dominant, 0)
        geom_dom = np.where(ret.dominant >= 0,
                            np.take_along_axis(geom, dom[..., None], axis=-1)[..., 0], -1)
        return ret, geom_dom

    def _footprints(self, theta: np.ndarray, rng: np.random.Generator, progress: Progress | None):
        """Combined footprint returns per beam: (FootprintReturn of (n_lines, n_beams), geom)."""
        n_lines, n_beams, S = len(theta), len(self.beam_angles_rad), self.n_sub
        per_beam = theta if theta.ndim == 2 else np.broadcast_to(theta[:, None], (n_lines, n_beams))
        pattern = self.pattern
        probe = pattern.probe if self.adaptive else np.arange(S)
        rest = np.setdiff1d(np.arange(S), probe)
        beams = np.arange(n_beams)
        variant = (rng.integers(self.n_variants, size=(n_lines, n_beams)) if self.n_variants > 1
                   else np.zeros((n_lines, n_beams), dtype=np.int64))
        first_id = (variant * n_beams + beams) * S  # the id of each footprint's sub-ray 0
        keys = ("range_m", "power", "cos_incidence", "spread_m")
        out = {k: np.full((n_lines, n_beams), np.nan) for k in keys}
        geom_out = np.full((n_lines, n_beams), -1, dtype=np.int32)
        self.n_refined = 0
        chunk = 64
        for lo in range(0, n_lines, chunk):
            hi = min(lo + chunk, n_lines)
            c = hi - lo
            var = variant[lo:hi]
            ids = first_id[lo:hi, :, None] + probe[None, None, :]
            self.n_subrays_probe += ids.size
            if theta.ndim == 1:  # one angle a line
                hits = self.caster.cast(ids.reshape(c, -1), theta[lo:hi], normals=True)
            else:  # one angle a beam: each beam's probes are a "line" of the caster
                hits = self.caster.cast(ids.reshape(c * n_beams, -1), per_beam[lo:hi].reshape(-1), normals=True,
                                        chunk_lines=c * n_beams)
            d = hits.dist_m.reshape(c, n_beams, len(probe))
            g = hits.geom_id.reshape(c, n_beams, len(probe))
            nrm = hits.normal_base.reshape(c, n_beams, len(probe), 3)
            # Only the probes' rays are gathered here ((c, n_beams, n_probe, 3)); a refined
            # beam's whole footprint is gathered in _refine.
            d_probe = take_rows(self.caster.dirs_base, ids)
            if self.adaptive:
                hit = take_rows(self.caster.origins_base, ids) + np.maximum(d, 0)[..., None] * d_probe
                refine = ~coplanar_probes(hit, nrm, g, tolerance_m=self.model.flat_tolerance_m)
                # Flat footprints: the axis ray stands for the whole footprint.
                ret, geom_dom = self._combine(d[:, :, :1], g[:, :, :1], nrm[:, :, :1], d_probe[:, :, :1], np.ones(1))
            else:
                refine = np.zeros((c, n_beams), dtype=bool)
                ret, geom_dom = self._combine(d, g, nrm, d_probe, self.weights[var, beams])
            for k in keys:
                out[k][lo:hi] = getattr(ret, k)
            geom_out[lo:hi] = geom_dom
            if refine.any():
                self._refine(out, geom_out, lo, refine, d, g, nrm, per_beam[lo:hi], probe, rest, var)
            if progress is not None:
                progress(hi, n_lines)
        log.debug("footprint: %d of %d beams refined with %d sub-rays", self.n_refined, n_lines * n_beams, S)
        return FootprintReturn(dominant=None, **out), geom_out

    def _refine(self, out, geom_out, lo, refine, d, g, nrm, theta, probe, rest, var):
        """Casts the other sub-rays of the flagged beams and combines all of them."""
        S = self.n_sub
        n_beams = refine.shape[1]
        line_of, beam_of = np.nonzero(refine)
        self.n_refined += len(line_of)
        self.n_beams_refined += len(line_of)
        n_rest = len(rest)
        self.n_subrays_refine += len(line_of) * n_rest
        variant = var[line_of, beam_of]
        # All the refined beams' other sub-rays in one flat selection, each at its beam's angle.
        # (Each refined beam is a "line" of the caster: one angle for its n_rest sub-rays.)
        first = (variant * n_beams + beam_of) * S  # the id of each refined footprint's sub-ray 0
        ids = first[:, None] + rest[None, :]
        hits = self.caster.cast(ids, theta[line_of, beam_of], normals=True, chunk_lines=max(len(ids), 1))
        d2 = hits.dist_m.reshape(-1, n_rest)
        g2 = hits.geom_id.reshape(-1, n_rest)
        n2 = hits.normal_base.reshape(-1, n_rest, 3)
        k = len(line_of)
        dist = np.empty((k, S))
        geom = np.empty((k, S), dtype=np.int32)
        normal = np.empty((k, S, 3))
        dist[:, probe], geom[:, probe], normal[:, probe] = d[line_of, beam_of], g[line_of, beam_of], \
            nrm[line_of, beam_of]
        dist[:, rest], geom[:, rest], normal[:, rest] = d2, g2, n2
        ret, geom_dom = self._combine(dist, geom, normal, take_rows(self.caster.dirs_base, first[:, None] + np.arange(S)),
                                      self.weights[variant, beam_of])
        rows = lo + line_of
        for key in ("range_m", "power", "cos_incidence", "spread_m"):
            out[key][rows, beam_of] = getattr(ret, key)
        geom_out[rows, beam_of] = geom_dom
