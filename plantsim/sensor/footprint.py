"""Beam footprint: sub-rays across a diverging beam and how their returns combine.

A real beam is not a ray: the URG-04LX's footprint is ~10 mrad wide, wider
than its 6.1 mrad step. Where a footprint straddles a leaf edge and what lies
behind it, a phase-measuring sensor reports one range between the two
surfaces (a "mixed pixel"). This module samples the footprint with sub-rays
on rings (HELIOS++'s scheme: 1 + 6 + 12 = 19 rays for two rings) and combines
their returns.

Sub-ray geometry, lidar frame: beam b has direction ``d = (cos a, sin a, 0)``
and transverse unit vectors ``e_in = (-sin a, cos a, 0)`` (in the scan plane)
and ``e_out = (0, 0, 1)`` (out of it). A sub-ray with unit offset ``(u, v)``
(1 = the 1/e^2 radius) starts at ``D0/2 (u e_in + v e_out)`` and points along
``d + (div/2)(u e_in + v e_out)`` (normalised), so its offset from the beam
axis at range r is ``(D0/2 + r div/2) (u, v)``: the 1/e^2 footprint radius.

Combination (a phase sensor measures the phase of the sum of the returned
modulated signals; for phase differences well under a radian this is the
power-weighted mean range):

    p_i = w_i * rho_i * cos(theta_i) / r_i^2       (received power, Lambertian
                                                   range equation)
    r   = sum(p_i r_i) / sum(p_i)
    w_i = exp(-2 (rho_i / w0)^2) / sum(...)        (Gaussian TEM00 profile)

with rho_i the sub-ray's offset radius in units of the 1/e^2 radius w0.

Mixed pixels as a continuum. A phase sensor integrates the whole footprint,
so as an edge crosses it the reported range moves continuously between the
two surfaces. A fixed set of sub-rays turns that into steps: the range
changes only when the edge passes a sub-ray. Two things undo the steps here:
each ring is turned by the golden angle against the one inside it (so no two
sub-rays share a projection on any axis of the pattern, and an edge crossing
the footprint passes them one at a time: n_sub + 1 levels, not a few). That
still leaves steps, because the weights are fixed: the mixture fraction is a
sum of a subset of them. :func:`jitter_subrays` removes them: each sub-ray
stands for an equal-area cell of the footprint (the axis disk, and on ring k
6k sectors of the annulus between radii (k -+ 1/2) / n_rings); drawn from the
run's generator, every sub-ray moves to a uniformly random point of its cell
and weighs the Gaussian profile there times its cell's area (stratified Monte
Carlo integration of the beam profile, unbiased for any scene). Sub-ray
positions and weights then vary continuously from beam to beam, and so do the
mixture fractions and the mixed-pixel ranges, which fill the whole interval
between the two surfaces as a phase sensor's do. With no rings (one ray per
beam) nothing moves: the ideal scan. A cheaper partial remedy is
a random turn of the whole pattern per beam (:func:`pattern_rotations_rad`,
``rotation_rad``).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

# Each ring is turned by this against the ring inside it (the golden angle,
# pi (3 - sqrt 5)): no two sub-rays of the pattern share an in-plane or an
# out-of-plane offset, so an edge crossing the footprint passes them one by one.
RING_TWIST_RAD = math.pi * (3.0 - math.sqrt(5.0))


@dataclasses.dataclass(frozen=True, eq=False)
class SubrayPattern:
    """Sub-ray offsets and weights across a footprint.

    Attributes:
      offsets: (n_sub, 2) float64, (in-plane, out-of-plane) offset in units of
        the 1/e^2 radius; row 0 is the beam axis (0, 0).
      weights: (n_sub,) float64, Gaussian profile weights summing to 1.
      probe: (n_probe,) int64, indices of the sub-rays cast first: the axis
        and four rays of the outer ring about 90 degrees apart. A footprint
        whose probes all land on one locally flat surface is not refined.
    """

    offsets: np.ndarray
    weights: np.ndarray
    probe: np.ndarray

    @property
    def n_subrays(self) -> int:
        return int(len(self.offsets))


def subray_pattern(n_rings: int) -> SubrayPattern:
    """Rings of sub-rays: 1 on the axis, 6k on ring k at radius k / n_rings.

    Each ray on ring k stands for an equal share of the annulus (6k rays for an
    area growing as k), so its weight is the Gaussian profile at its radius,
    ``exp(-2 rho^2)`` (HELIOS++, Winiwarter et al. 2022; PlantSimulationLab
    Helios' Gaussian beam). 0 rings is one ray. Ring k is turned by
    ``k * RING_TWIST_RAD`` (see the module's note on mixed pixels).

    Args:
      n_rings: number of rings (>= 0); 1 -> 7 rays, 2 -> 19, 3 -> 37.

    Raises:
      ValueError: n_rings is not a non-negative integer.
    """
    if isinstance(n_rings, bool) or int(n_rings) != n_rings or n_rings < 0:
        raise ValueError(f"n_rings must be a non-negative integer, got {n_rings!r}")
    n_rings = int(n_rings)
    offsets = [np.zeros((1, 2))]
    for k in range(1, n_rings + 1):
        phi = 2 * np.pi * np.arange(6 * k) / (6 * k) + k * RING_TWIST_RAD
        offsets.append((k / n_rings) * np.stack([np.cos(phi), np.sin(phi)], axis=1))
    offsets = np.concatenate(offsets)
    weights = np.exp(-2.0 * np.sum(offsets ** 2, axis=1))
    weights /= weights.sum()
    if n_rings == 0:
        probe = np.array([0])
    else:
        first = 1 + 3 * n_rings * (n_rings - 1)  # index of the outer ring's ray at phi = 0
        quarter = sorted({int(round(6 * n_rings * q / 4)) for q in range(4)})
        probe = np.array([0] + [first + j for j in quarter])
    return SubrayPattern(offsets=offsets, weights=weights, probe=probe)


def pattern_rotations_rad(rng: np.random.Generator, shape) -> np.ndarray:
    """Random turns of the sub-ray pattern about the beam axis, uniform in [0, 2 pi).

    Draw them from the run's generator, one per beam (fixed ray table) or one
    per beam and line, and pass them as ``rotation_rad`` to :func:`subrays_lidar`.

    Args:
      rng: the run's generator (one ``uniform`` draw of ``shape``).
      shape: e.g. ``(n_beams,)`` or ``(n_lines, n_beams)``.

    Returns:
      ``shape`` float64 radians.
    """
    return rng.uniform(0.0, 2.0 * np.pi, size=shape)


def pattern_rings(pattern: SubrayPattern) -> int:
    """The number of rings of a :func:`subray_pattern` (1 + 3 n (n + 1) sub-rays)."""
    n = int(round((-3 + math.sqrt(9 + 12 * (pattern.n_subrays - 1))) / 6))
    if 1 + 3 * n * (n + 1) != pattern.n_subrays:
        raise ValueError(f"not a ring pattern: {pattern.n_subrays} sub-rays")
    return n


def jitter_subrays(pattern: SubrayPattern, rng: np.random.Generator, shape
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Each sub-ray at a random point of its equal-area cell, weighted by the profile there.

    Stratified Monte Carlo sampling of the Gaussian beam (see the module's
    note on mixed pixels). Ring k (of n) owns the annulus between radii
    (k - 1/2)/n and (k + 1/2)/n (the outer ring's reaches past the 1/e^2
    radius into the profile's tail), cut into 6k sectors centred on the
    pattern's sub-rays; the axis sub-ray owns the disk of radius 1/(2n). A sub-ray's weight is ``exp(-2 rho^2)`` at its new position times
    its cell's area, normalised per beam.

    Args:
      pattern: a :func:`subray_pattern`.
      rng: the run's generator (two ``random`` draws of ``shape + (n_sub,)``).
      shape: leading shape, e.g. ``(n_beams,)`` or ``(n_lines, n_beams)``.

    Returns:
      offsets (*shape, n_sub, 2) float64 in units of the 1/e^2 radius (pass
      as ``offsets`` to :func:`subrays_lidar`), and weights (*shape, n_sub)
      float64 summing to 1 (pass to :func:`combine_footprint`).
    """
    n = pattern_rings(pattern)
    shape = (int(shape),) if isinstance(shape, (int, np.integer)) else tuple(shape)
    S = pattern.n_subrays
    if n == 0:
        return np.zeros(shape + (1, 2)), np.ones(shape + (1,))
    ring = np.concatenate([[0]] + [np.full(6 * k, k) for k in range(1, n + 1)])
    phi_c = np.arctan2(pattern.offsets[:, 1], pattern.offsets[:, 0])
    u, v = rng.random(shape + (S,)), rng.random(shape + (S,))
    r0 = np.maximum(ring - 0.5, 0.0) / n
    r1 = (ring + 0.5) / n
    rho = np.sqrt(r0 ** 2 + u * (r1 ** 2 - r0 ** 2))
    half = np.where(ring > 0, np.pi / np.maximum(6 * ring, 1), 0.0)
    phi = phi_c + (2 * v - 1) * half
    phi = np.where(ring > 0, phi, 2 * np.pi * v)
    # A sector of angle 2 half between r0 and r1 has area (r1^2 - r0^2) half; the axis disk pi r1^2.
    area = np.where(ring > 0, (r1 ** 2 - r0 ** 2) * half, np.pi * r1 ** 2)
    offsets = np.stack([rho * np.cos(phi), rho * np.sin(phi)], axis=-1)
    weights = np.exp(-2.0 * rho ** 2) * area
    weights /= weights.sum(axis=-1, keepdims=True)
    return offsets, weights


def subrays_lidar(beam_angles_rad: np.ndarray, pattern: SubrayPattern, *,
                  divergence_rad: float, exit_diameter_m: float,
                  rotation_rad: np.ndarray | None = None,
                  offsets: np.ndarray | None = None,
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Origins and directions of every sub-ray of every beam, lidar frame.

    The axis sub-ray (row 0) is exactly ``beam_dirs_lidar`` (not renormalised),
    so a one-ray pattern casts the same rays as the ideal scanner.

    Args:
      beam_angles_rad: (n_beams,) float64, radians.
      pattern: the footprint sampling.
      divergence_rad: full angle of the 1/e^2 cone.
      exit_diameter_m: 1/e^2 diameter at the optical centre, metres.
      rotation_rad: None (the pattern as it is), or a turn of the pattern
        about each beam's axis, radians, of shape (n_beams,) or
        (..., n_beams) (e.g. (n_lines, n_beams): a new turn per line;
        :func:`pattern_rotations_rad`).
      offsets: None (the pattern's), or per-beam sub-ray offsets of shape
        (..., n_beams, n_sub, 2) from :func:`jitter_subrays`; then
        ``rotation_rad`` must be None.

    Returns:
      origins_lidar (..., n_beams, n_sub, 3) float64 metres, dirs_lidar
      (..., n_beams, n_sub, 3) float64 unit vectors; the leading ``...`` is
      that of ``rotation_rad`` or ``offsets`` (none without them).
    """
    a = np.asarray(beam_angles_rad, dtype=np.float64)
    d = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=-1)
    e_in = np.stack([-np.sin(a), np.cos(a), np.zeros_like(a)], axis=-1)
    e_out = np.broadcast_to(np.array([0.0, 0.0, 1.0]), d.shape)
    u0, v0 = pattern.offsets[:, 0], pattern.offsets[:, 1]
    if offsets is not None:
        off = np.asarray(offsets, dtype=np.float64)
        if rotation_rad is not None:
            raise ValueError("give rotation_rad or offsets, not both")
        if off.shape[-3:] != (len(a), pattern.n_subrays, 2):
            raise ValueError(f"offsets must have shape (..., {len(a)}, {pattern.n_subrays}, 2), "
                             f"got shape {off.shape}")
        u, v = off[..., 0], off[..., 1]
    elif rotation_rad is None:
        u, v = u0[None, :], v0[None, :]
    else:
        rot = np.asarray(rotation_rad, dtype=np.float64)
        if rot.shape[-1:] != a.shape:
            raise ValueError(f"rotation_rad must have shape (..., n_beams) with n_beams = {len(a)}, "
                             f"got shape {rot.shape}")
        c, s_ = np.cos(rot)[..., None], np.sin(rot)[..., None]
        u, v = c * u0 - s_ * v0, s_ * u0 + c * v0  # (..., n_beams, n_sub)
    transverse = u[..., None] * e_in[:, None, :] + v[..., None] * e_out[:, None, :]
    origins = 0.5 * exit_diameter_m * transverse
    dirs = d[:, None, :] + 0.5 * divergence_rad * transverse
    dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)
    dirs[..., 0, :] = d
    return origins, dirs


@dataclasses.dataclass(frozen=True, eq=False)
class FootprintReturn:
    """What a beam's footprint returned, combined (no noise yet).

    Attributes (all (...) per beam):
      range_m: float64, power-weighted mean range, metres; NaN with no echo.
      power: float64, received power sum(w_i rho_i cos_i / r_i^2), m^-2.
      cos_incidence: float64, power-weighted mean cos(incidence).
      spread_m: float64, power-weighted standard deviation of the sub-ray
        ranges, metres (0 on one flat surface).
      dominant: int64, index of the sub-ray with the most power (-1: no echo).
    """

    range_m: np.ndarray
    power: np.ndarray
    cos_incidence: np.ndarray
    spread_m: np.ndarray
    dominant: np.ndarray


def combine_footprint(dist_m: np.ndarray, cos_incidence: np.ndarray, reflectance: np.ndarray,
                      weights: np.ndarray, *, range_max_m: float) -> FootprintReturn:
    """Combines sub-ray returns as a phase-measuring sensor does.

    Args:
      dist_m: (..., n_sub) float64, first-hit distance per sub-ray, -1 for a miss.
      cos_incidence: (..., n_sub) float64, |cos| of the angle between the
        sub-ray and the surface normal.
      reflectance: (..., n_sub) float64, Lambertian reflectance of what was hit.
      weights: (n_sub,) or (..., n_sub) float64, beam profile weights.
      range_max_m: sub-ray hits beyond this return nothing.

    Returns:
      :class:`FootprintReturn` with the leading shape of ``dist_m``.
    """
    valid = (dist_m >= 0) & (dist_m <= range_max_m)
    r = np.where(valid, dist_m, 1.0)
    # Received power, Lambertian range equation P ~ rho cos(theta) / r^2 (the
    # tiny floor only guards a hit at the optical centre itself).
    p = np.where(valid, weights * reflectance * cos_incidence / np.maximum(r, 1e-6) ** 2, 0.0)
    power = p.sum(axis=-1)
    any_echo = valid.any(axis=-1) & (power > 0)
    safe = np.where(any_echo, power, 1.0)
    dominant = np.argmax(p, axis=-1)
    # The mean as an offset from the strongest return: exactly that return's
    # range when it is the only one (so one ray per beam is the ideal scan).
    r_dom = np.take_along_axis(r, dominant[..., None], axis=-1)
    offset = np.where(valid, r - r_dom, 0.0)
    range_m = np.where(any_echo, r_dom[..., 0] + (p * offset).sum(axis=-1) / safe, np.nan)
    cos_mean = np.where(any_echo, (p * cos_incidence).sum(axis=-1) / safe, np.nan)
    deviation = np.where(valid, r - np.nan_to_num(range_m)[..., None], 0.0)
    spread = np.where(any_echo, np.sqrt((p * deviation ** 2).sum(axis=-1) / safe), np.nan)
    dominant = np.where(any_echo, dominant, -1)
    return FootprintReturn(range_m=range_m, power=power, cos_incidence=cos_mean,
                           spread_m=spread, dominant=dominant)


def coplanar_probes(hit_base: np.ndarray, normal_base: np.ndarray, geom_id: np.ndarray, *,
                    tolerance_m: float) -> np.ndarray:
    """Whether a beam's probe sub-rays all land on one locally flat surface.

    Args:
      hit_base: (..., n_probe, 3) float64 metres, probe hit points (probe 0 is
        the axis ray).
      normal_base: (..., n_probe, 3) float64, surface normals at the hits.
      geom_id: (..., n_probe) int32, MuJoCo geom id (-1: miss).
      tolerance_m: largest distance of a probe's hit from the plane through
        the axis hit, perpendicular to its normal.

    Returns:
      (...) bool: True where the footprint needs no refinement.
    """
    same = np.all(geom_id == geom_id[..., :1], axis=-1)
    hit = geom_id[..., 0] >= 0
    offset = hit_base - hit_base[..., :1, :]
    n0 = normal_base[..., :1, :]  # the axis hit's normal, against every probe
    height = np.abs(offset[..., 0] * n0[..., 0] + offset[..., 1] * n0[..., 1] + offset[..., 2] * n0[..., 2])
    flat = np.all(height <= tolerance_m, axis=-1)
    # All probes missing is flat too: nothing there to refine.
    return (same & (~hit | flat))
