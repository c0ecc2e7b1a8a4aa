"""Range-image denoising: a robust local-plane fit of each beam's range among its neighbours.

A 2D LiDAR on a turntable measures a range image: one row per scan line (turntable
angle), one column per beam (elevation in the fan). The URG-04LX's random range noise
(about 10 mm, :mod:`plantsim.sensor.spec`) lies along each beam and matches the width
of a wheat leaf, while neighbouring beams 2 mm apart see the same surface. Filtering
the ranges in the image, before the points are made, trades a few millimetres of
lateral blur for a several-fold smaller noise, and moves each point only along its own
beam, the direction the noise is in.

Method (a robust bilateral filter, Tomasi & Manduchi 1998, "Bilateral filtering for
gray and color images", ICCV; with a local linear fit instead of a weighted mean, as in
local regression, Cleveland 1979, so a surface seen obliquely keeps its slope and a
leaf's edge is not pulled towards its centre):

1. Rows are ordered by turntable angle (modulo one turn); a scan that covers the full
   turn wraps, so its first and last lines are neighbours.
2. Each beam's window is ``(2 half_lines + 1) x (2 half_beams + 1)`` beams round it;
   misses are not values.
3. The window's median range picks the surface most of the window sees (a lone mixed
   pixel between two surfaces, or a speck, is not it).
4. The noise ``sigma`` is measured on the scan itself: 1.4826 times the median absolute
   deviation of the ranges from their window medians (Rousseeuw & Croux 1993), or given.
5. The neighbours within ``gate_sigma * sigma`` of the median are the beam's surface;
   a plane ``r = a + b i + c j`` (row offset ``i``, beam offset ``j``) is fitted to them
   by least squares, and the beam's range becomes ``a``. A beam with fewer than
   ``min_support`` such neighbours (an organ one or two beams wide) keeps its range.

Validity: surfaces wider than the window (about ``2 half_beams + 1`` beams along the
fan and ``2 half_lines + 1`` lines across it); two surfaces closer in range than about
``gate_sigma * sigma`` inside one window are averaged into one (they are not resolved
by the raw ranges either). Lateral resolution falls to about the window's size; a
curved surface is flattened by its curvature over the window (a 4 mm stem seen over
7 beams at 0.35 m is). With no noise measured (an ideal scan) the ranges are returned
unchanged.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from plantsim.scan.config import RangeFilter
from plantsim.scan.raw import RawScan, believed_angles
from plantsim.sensor.spec import BeamStatus

__all__ = ["RangeFilterReport", "filter_range_image", "filter_ranges"]

# 1 / Phi^-1(3/4): the median absolute deviation of a normal sample times this is its sigma.
_MAD_TO_SIGMA = 1.4826
# Rows per block of the sliding window (bounds memory: rows x beams x window values).
_BLOCK_ROWS = 64


@dataclasses.dataclass(frozen=True)
class RangeFilterReport:
    """What the filter did, for the sidecar.

    Attributes:
      sigma_m: the noise used, metres.
      sigma_measured: True when measured on the scan, False when given.
      returns: beams with a range.
      filtered: returns whose range was refitted.
      unsupported: returns that kept their range (fewer than ``min_support`` neighbours
        on their surface).
      wrapped: the rows cover the full turn, first and last lines neighbours.
      median_change_m: median absolute change of the refitted ranges, metres.
    """

    sigma_m: float
    sigma_measured: bool
    returns: int
    filtered: int
    unsupported: int
    wrapped: bool
    median_change_m: float

    def to_dict(self, settings: RangeFilter) -> dict[str, Any]:
        return {
            "method": "robust local-plane fit in the range image (median-gated bilateral filter)",
            "window_lines": 2 * settings.half_lines + 1, "window_beams": 2 * settings.half_beams + 1,
            "gate_sigma": settings.gate_sigma, "min_support": settings.min_support,
            **dataclasses.asdict(self),
        }


def _windows(padded: np.ndarray, rows: slice, hl: int, hb: int, n_cols: int) -> np.ndarray:
    """(rows, cols, window) values of the padded image round each pixel of ``rows``."""
    block = padded[rows.start:rows.stop + 2 * hl]
    view = np.lib.stride_tricks.sliding_window_view(block, (2 * hl + 1, 2 * hb + 1))
    return view.reshape(view.shape[0], n_cols, -1)


def _median_ignoring_nan(values: np.ndarray) -> np.ndarray:
    """Median over the last axis, NaN ignored (NaN where all are NaN), without warnings."""
    ordered = np.sort(values, axis=-1)  # NaN sort last
    count = np.isfinite(values).sum(axis=-1)
    lo = np.take_along_axis(ordered, (np.maximum(count - 1, 0) // 2)[..., None], axis=-1)[..., 0]
    hi = np.take_along_axis(ordered, (count // 2)[..., None], axis=-1)[..., 0]
    return np.where(count > 0, 0.5 * (lo + hi), np.nan)


def filter_range_image(range_m: Any, *, settings: RangeFilter = RangeFilter(), wrap_rows: bool = False
                       ) -> tuple[np.ndarray, float, np.ndarray]:
    """Denoise a range image (method in the module docstring). Pure: no I/O.

    Args:
      range_m: (rows, beams) float64, metres; NaN where there is no return. Rows are
        neighbouring scan lines in order.
      settings: the window, gate and support (``enabled`` is not read here).
      wrap_rows: the last row neighbours the first (a full turn).

    Returns:
      (filtered (rows, beams) float64 metres, NaN where the input is; the noise sigma
      used, metres; (rows, beams) bool, the returns that were refitted).
    """
    image = np.asarray(range_m, dtype=np.float64)
    if image.ndim != 2:
        raise ValueError(f"range_m must be a 2-D image (lines, beams), got shape {image.shape}")
    valid = np.isfinite(image)
    out = image.copy()
    refitted = np.zeros(image.shape, dtype=bool)
    hl, hb = settings.half_lines, settings.half_beams
    if not valid.any():
        return out, 0.0 if settings.sigma_m is None else float(settings.sigma_m), refitted
    cols = np.flatnonzero(valid.any(axis=0))
    c0, c1 = int(cols[0]), int(cols[-1]) + 1
    sub = image[:, c0:c1]
    n_rows, n_cols = sub.shape
    if wrap_rows and n_rows > 2 * hl:
        padded = np.concatenate([sub[n_rows - hl:], sub, sub[:hl]], axis=0) if hl else sub
    else:
        padded = np.pad(sub, ((hl, hl), (0, 0)), constant_values=np.nan)
    padded = np.pad(padded, ((0, 0), (hb, hb)), constant_values=np.nan)
    di, dj = (a.ravel().astype(np.float64) for a in
              np.meshgrid(np.arange(-hl, hl + 1), np.arange(-hb, hb + 1), indexing="ij"))

    medians = np.empty_like(sub)
    for start in range(0, n_rows, _BLOCK_ROWS):
        rows = slice(start, min(start + _BLOCK_ROWS, n_rows))
        medians[rows] = _median_ignoring_nan(_windows(padded, rows, hl, hb, n_cols))
    sub_valid = valid[:, c0:c1]
    if settings.sigma_m is None:
        sigma = _MAD_TO_SIGMA * float(np.median(np.abs(sub - medians)[sub_valid]))
    else:
        sigma = float(settings.sigma_m)
    if sigma <= 0.0:
        return out, sigma, refitted

    # Per pixel, the weighted moments of a least-squares plane r = a + b i + c j over
    # the gated neighbours; a tiny ridge on b, c makes a one-row or one-column support
    # a line fit (or a mean) instead of a singular system.
    gate = settings.gate_sigma * sigma
    result, done = out[:, c0:c1], refitted[:, c0:c1]  # views: written in place
    for start in range(0, n_rows, _BLOCK_ROWS):
        rows = slice(start, min(start + _BLOCK_ROWS, n_rows))
        win = _windows(padded, rows, hl, hb, n_cols)
        w = (np.abs(win - medians[rows][..., None]) <= gate)  # NaN compares False
        r = np.where(w, win - medians[rows][..., None], 0.0)  # ranges relative to the median
        wf = w.astype(np.float64)
        n = wf.sum(-1)
        si, sj = wf @ di, wf @ dj
        sii, sjj, sij = wf @ (di * di), wf @ (dj * dj), wf @ (di * dj)
        sr, sri, srj = r.sum(-1), r @ di, r @ dj
        ridge = 1e-6
        m = np.stack([np.stack([n, si, sj], -1), np.stack([si, sii + ridge, sij], -1),
                      np.stack([sj, sij, sjj + ridge], -1)], -2)
        rhs = np.stack([sr, sri, srj], -1)
        ok = sub_valid[rows] & (n >= settings.min_support)
        if ok.any():
            fit = np.linalg.solve(m[ok], rhs[ok][..., None])[..., 0]
            result[rows][ok] = medians[rows][ok] + fit[:, 0]
            done[rows] = ok
    return out, sigma, refitted


def _row_order(raw: RawScan) -> tuple[np.ndarray, bool]:
    """Lines in order of turntable angle (mod one turn), and whether they wrap round."""
    if raw.n_lines == 0:
        return np.zeros(0, dtype=np.int64), False
    lines = np.arange(raw.n_lines)
    angle = np.mod(believed_angles(raw, lines, np.full(raw.n_lines, raw.n_beams // 2)), 2.0 * math.pi)
    order = np.argsort(angle, kind="stable")
    if raw.n_lines < 3:
        return order, False
    sorted_angle = angle[order]
    gaps = np.diff(sorted_angle)
    closing = sorted_angle[0] + 2.0 * math.pi - sorted_angle[-1]
    step = float(np.median(gaps))
    return order, bool(step > 0 and closing <= 1.5 * step)


def filter_ranges(raw: RawScan, settings: RangeFilter = RangeFilter()) -> tuple[RawScan, RangeFilterReport]:
    """A raw scan with its ranges denoised (module docstring), and what was done.

    Only the ranges of returns change; statuses, angles, times and intensities stay.
    The raw record a scan writes keeps the sensor's own ranges: filter when reconstructing.

    Args:
      raw: the raw record (simulated or from the real rig).
      settings: the filter's settings.

    Returns:
      (the filtered raw scan, :class:`RangeFilterReport`).
    """
    ok = raw.status == BeamStatus.OK
    image = np.where(ok, raw.range_m, np.nan)
    order, wrapped = _row_order(raw)
    filtered_sorted, sigma, refitted_sorted = filter_range_image(image[order], settings=settings,
                                                                 wrap_rows=wrapped)
    filtered = np.empty_like(filtered_sorted)
    filtered[order] = filtered_sorted
    refitted = np.empty_like(refitted_sorted)
    refitted[order] = refitted_sorted
    new_range = np.where(ok, filtered, raw.range_m)
    change = np.abs(new_range - raw.range_m)[refitted]
    report = RangeFilterReport(
        sigma_m=sigma, sigma_measured=settings.sigma_m is None, returns=int(ok.sum()),
        filtered=int(refitted.sum()), unsupported=int(ok.sum() - refitted.sum()), wrapped=wrapped,
        median_change_m=float(np.median(change)) if len(change) else 0.0)
    return raw.replace(range_m=new_range), report
