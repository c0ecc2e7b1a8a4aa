"""Ray casting for the simulated LiDAR: MuJoCo's ``mujoco.batch`` on the scan scene."""

from __future__ import annotations

import logging
import os
from typing import Callable

import mujoco
import mujoco.batch
import numpy as np

from plantsim.rig.geometry import beam_dirs_lidar
from plantsim.rig.scene import LIDAR_GEOMGROUP, Scene
from plantsim.sensor.footprint import SubrayPattern, coplanar_probes, combine_footprint, subray_pattern, subrays_lidar
from plantsim.sensor.model import SensorModel
from plantsim.sensor.spec import BeamStatus, LidarSpec
from plantsim.transforms import rot_z_batch

log = logging.getLogger(__name__)

Progress = Callable[[int, int], None]


# MuJoCo's mesh BVH can cull a ray that lies exactly in a plane holding mesh
# vertices (../shared/notes/mujoco-raycasting.md): a scan plane through the
# turntable axis is that case at every angle where the plant has a vertex row.
# Moving every origin this far off the scan plane, along its normal, removes
# it; the reconstruction error it adds is at most this distance.
AXIS_TRAP_OFFSET_M = 1e-9


def ray_origins_dirs_base(T_base_lidar: np.ndarray, beam_angles_rad: np.ndarray
                          ) -> tuple[np.ndarray, np.ndarray]:
    """World-frame rays of one scan line, with the axis-trap guard applied.

    Returns:
      origin_base (3,) float64 metres, dirs_base (n_beams, 3) float64 unit vectors.
    """
    R = T_base_lidar[:3, :3]
    dirs_base = beam_dirs_lidar(beam_angles_rad) @ R.T
    origin_base = T_base_lidar[:3, 3] + AXIS_TRAP_OFFSET_M * R[:, 2]
    return origin_base, dirs_base


def gate_ranges(dist_m: np.ndarray, lidar: LidarSpec) -> tuple[np.ndarray, np.ndarray]:
    """Applies the sensor's range limits to first-hit distances.

    Args:
      dist_m: (...) float64 metres, MuJoCo's first-hit distance, -1 for a miss.
      lidar: the sensor.

    Returns:
      range_m (...) float64 with NaN where there is no return, status (...) uint8.
    """
    status = np.full(dist_m.shape, BeamStatus.OK, dtype=np.uint8)
    status[(dist_m < 0) | (dist_m > lidar.range_max_m)] = BeamStatus.NO_ECHO
    status[(dist_m >= 0) & (dist_m < lidar.range_min_m)] = BeamStatus.TOO_NEAR
    range_m = np.where(status == BeamStatus.OK, dist_m, np.nan)
    return range_m, status


class RayCaster:
    """Casts LiDAR lines at given turntable angles with ``mujoco.batch``.

    One simulation per scan line: its hinge angle is that line's, and all lines
    share the same world-frame rays. The batch releases the GIL and runs on
    ``nthread`` threads.
    """

    def __init__(self, scene: Scene, lidar: LidarSpec, *, nthread: int | None = None,
                 max_lines: int = 4096):
        self.scene = scene
        self.lidar = lidar
        self.beam_angles_rad = lidar.beam_angles_rad()
        self.origin_base, self.dirs_base = ray_origins_dirs_base(scene.T_base_lidar,
                                                                  self.beam_angles_rad)
        self.nthread = nthread or max(1, os.cpu_count() or 1)
        self._max_lines = max_lines
        self._batch = None
        self._nsim = 0

    def _ensure_batch(self, n: int):
        if self._batch is None or self._nsim < n:
            self._nsim = max(n, 1)
            self._batch = mujoco.batch.Batch(self.scene.model, nsim=self._nsim, nthread=self.nthread)
        return self._batch

    def cast(self, qpos_turntable_rad: np.ndarray, *, progress: Progress | None = None,
             chunk_lines: int = 64) -> tuple[np.ndarray, np.ndarray]:
        """First-hit distance and geom per beam, one line per turntable angle.

        Args:
          qpos_turntable_rad: (n_lines,) float64, the true hinge angle per line.
          progress: called with (lines done, lines total) after each chunk.
          chunk_lines: lines per batch call (progress granularity).

        Returns:
          dist_m (n_lines, n_beams) float64 (-1: miss), geom_id (n_lines, n_beams) int32.
        """
        q = np.asarray(qpos_turntable_rad, dtype=np.float64).reshape(-1)
        n = len(q)
        dist = np.empty((n, len(self.dirs_base)))
        geom = np.empty((n, len(self.dirs_base)), dtype=np.int32)
        adr = self.scene.turntable_qpos_adr
        for start in range(0, n, self._max_lines):
            block = q[start:start + self._max_lines]
            batch = self._ensure_batch(len(block))
            qpos = batch.bind("qpos")
            qpos[: len(block), adr] = block
            for lo in range(0, len(block), chunk_lines):
                ids = np.arange(lo, min(lo + chunk_lines, len(block)))
                d, g = batch.ray(self.origin_base, self.dirs_base, geomgroup=LIDAR_GEOMGROUP,
                                 flg_static=True, bodyexclude=self.scene.lidar_body_id, ids=ids)
                dist[start + ids] = d
                geom[start + ids] = g
                if progress is not None:
                    progress(start + ids[-1] + 1, n)
        return dist, geom


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


def _groups(*groups: int) -> np.ndarray:
    return np.array([1 if g in groups else 0 for g in range(mujoco.mjNGROUP)], dtype=np.uint8)


TURNING_GEOMGROUP = _groups(1, 2)  # disk and plant: they turn with the table


FIXED_GEOMGROUP = _groups(0)  # bench, servo housing, post


class PoseCaster:
    """Casts every beam at its own turntable angle (see the module docstring)."""

    def __init__(self, scene: Scene, lidar: LidarSpec, *, nthread: int | None = None, nsim: int = 64):
        self.scene = scene
        self.lidar = lidar
        self.beam_angles_rad = lidar.beam_angles_rad()
        self.origin_base, self.dirs_base = ray_origins_dirs_base(scene.T_base_lidar, self.beam_angles_rad)
        self.nsim = nsim
        nthread = nthread or max(1, os.cpu_count() or 1)
        # Every simulation keeps the hinges at 0: the turntable frame is the base frame.
        self._batch = mujoco.batch.Batch(scene.model, nsim=nsim, nthread=nthread)
        d, g = self._batch.ray(self.origin_base, self.dirs_base, geomgroup=FIXED_GEOMGROUP,
                               flg_static=True, bodyexclude=scene.lidar_body_id, ids=np.array([0]))
        self._rig_dist, self._rig_geom = d[0], g[0]

    def cast(self, table_rad: np.ndarray, *, progress: Progress | None = None
             ) -> tuple[np.ndarray, np.ndarray]:
        """First hits of every beam at its own true table angle.

        Args:
          table_rad: (n_lines, n_beams) float64, true turntable angle per beam.
          progress: called with (lines done, lines total).

        Returns:
          dist_m (n_lines, n_beams) float64 (-1: miss), geom_id (n_lines, n_beams) int32.
        """
        theta = np.asarray(table_rad, dtype=np.float64)
        n_lines, n_beams = theta.shape
        dist = np.empty(theta.shape)
        geom = np.empty(theta.shape, dtype=np.int32)
        for lo in range(0, n_lines, self.nsim):
            hi = min(lo + self.nsim, n_lines)
            R_turntable_base = rot_z_batch(-theta[lo:hi].ravel()).reshape(hi - lo, n_beams, 3, 3)
            origins_turntable = R_turntable_base @ self.origin_base
            dirs_turntable = np.einsum("lbij,bj->lbi", R_turntable_base, self.dirs_base)
            d, g = self._batch.ray(origins_turntable, dirs_turntable, geomgroup=TURNING_GEOMGROUP,
                                   flg_static=False, bodyexclude=self.scene.lidar_body_id,
                                   ids=np.arange(hi - lo))
            rig_nearer = (self._rig_dist >= 0) & ((d < 0) | (self._rig_dist < d))
            dist[lo:hi] = np.where(rig_nearer, self._rig_dist, d)
            geom[lo:hi] = np.where(rig_nearer, self._rig_geom, g)
            if progress is not None:
                progress(hi, n_lines)
        return dist, geom
