"""Fit the sensor model to a real unit: noise, bias and warm-up drift from a flat-target recording.

Record the LiDAR looking at a flat matte plate at several known distances
(and, for the reflectance walk, plates of several known reflectances), ideally
starting at power-on so the warm-up drift is in the recording. Then
:func:`fit_sensor` estimates, by least squares on the range residuals
``e = measured - true``:

1. the systematic part (:func:`plantsim.sensor.model.range_bias`)

       e ~ b0 + b_rel r + b_dark (1 - rho) + A exp(-t / tau)

   linear in (b0, b_rel, b_dark, A) for each tau; tau is found on a
   logarithmic grid (10 s to 3 h) and refined by a parabola through the best
   three grid points. Terms the recording cannot separate (one distance: no
   scale; one reflectance: no walk; no warm-up in the recording: no drift)
   are left out and reported as not fitted (0 in the preset);
2. the random part (:func:`plantsim.sensor.model.range_sigma`, the
   "received-power" law): the squared residuals left after (1) have the
   expectation ``sigma0^2 + rel^2 r_eq^2 + q^2 / 12`` (``r_eq = r /
   sqrt(rho cos)``, ``q`` the range resolution), linear in (sigma0^2, rel^2);
   solved by iteratively re-weighted least squares (weights 1/var^2, the
   variance of a squared Gaussian residual), with residuals beyond 5 sigma
   (mixed pixels at the plate's edges, stray returns) left out.

Beams within ``edge_margin_m`` of the plate's edges are never used.
:meth:`SensorFit.to_toml` writes the result as ``[lidar]`` overrides of a
preset, a file ``plantsim scan --config`` reads.
"""

from __future__ import annotations

import dataclasses
import logging
import math

import numpy as np

from plantsim.sensor.flat_target import FlatTarget
from plantsim.sensor.spec import PRESETS

log = logging.getLogger(__name__)

TAU_GRID_S = np.geomspace(10.0, 3.0 * 3600.0, 241)
# A drift is only fitted when exp(-t/tau) changes by at least this much over
# the recording (otherwise it cannot be told from the constant offset).
MIN_DRIFT_CONTRAST = 0.3
OUTLIER_SIGMAS = 5.0


@dataclasses.dataclass(frozen=True, kw_only=True, eq=False)
class FlatTargetRecording:
    """A raw recording of a flat target at known geometry.

    Attributes:
      range_m: (n_lines, n_beams) float64 metres, the reported ranges; NaN
        where the sensor gave no range (error codes).
      beam_angles_rad: (n_beams,) float64 radians, lidar frame.
      time_since_power_on_s: (n_lines,) float64 seconds since the sensor was
        switched on, per line (the line's time stamp plus the time the sensor
        had been on when the recording started).
      target: the plate's geometry and reflectance per line.
      range_resolution_m: the sensor's range step (1 mm for the Hokuyos); its
        quantisation variance q^2/12 is not counted as noise.
    """

    range_m: np.ndarray
    beam_angles_rad: np.ndarray
    time_since_power_on_s: np.ndarray
    target: FlatTarget
    range_resolution_m: float = 0.001

    def __post_init__(self):
        r = np.asarray(self.range_m, dtype=np.float64)
        a = np.asarray(self.beam_angles_rad, dtype=np.float64)
        t = np.asarray(self.time_since_power_on_s, dtype=np.float64)
        if r.ndim != 2:
            raise ValueError(f"range_m must have shape (n_lines, n_beams), got shape {r.shape}")
        if a.shape != (r.shape[1],):
            raise ValueError(f"beam_angles_rad must have shape ({r.shape[1]},) to match range_m, "
                             f"got shape {a.shape}")
        if t.shape != (r.shape[0],):
            raise ValueError(f"time_since_power_on_s must have shape ({r.shape[0]},) (one time per "
                             f"line), got shape {t.shape}")
        if not np.all(np.isfinite(t)) or np.any(t < 0):
            raise ValueError("time_since_power_on_s must be finite and >= 0 on every line")
        if self.target.n_lines != r.shape[0]:
            raise ValueError(f"target has {self.target.n_lines} lines, range_m has {r.shape[0]}")
        q = self.range_resolution_m
        if isinstance(q, bool) or not isinstance(q, (int, float)) or not math.isfinite(q) or q < 0:
            raise ValueError(f"range_resolution_m must be a finite number >= 0, got {q!r}")
        object.__setattr__(self, "range_m", r)
        object.__setattr__(self, "beam_angles_rad", a)
        object.__setattr__(self, "time_since_power_on_s", t)


@dataclasses.dataclass(frozen=True, kw_only=True)
class SensorFit:
    """The fitted sensor parameters (names as in :class:`plantsim.sensor.spec.LidarSpec`).

    A term the recording could not separate is None (and 0 in the preset).

    Attributes:
      range_sigma_m, range_sigma_rel: the random noise (received-power law).
      range_bias_m, range_bias_rel, range_bias_dark_m: the systematic error.
      warmup_drift_m, warmup_time_constant_s: the warm-up drift.
      n_returns: residuals used.
      n_outliers: residuals left out as beyond 5 sigma.
      rms_residual_m: RMS of the residuals after the systematic fit.
    """

    range_sigma_m: float
    range_sigma_rel: float
    range_bias_m: float
    range_bias_rel: float | None
    range_bias_dark_m: float | None
    warmup_drift_m: float | None
    warmup_time_constant_s: float | None
    n_returns: int
    n_outliers: int
    rms_residual_m: float

    def lidar_overrides(self) -> dict:
        """The ``[lidar]`` keys this fit sets (not-fitted terms as 0)."""
        out = {"noise_law": "received-power", "range_sigma_m": self.range_sigma_m,
               "range_sigma_rel": self.range_sigma_rel, "range_bias_m": self.range_bias_m,
               "range_bias_rel": self.range_bias_rel or 0.0,
               "range_bias_dark_m": self.range_bias_dark_m or 0.0,
               "warmup_drift_m": self.warmup_drift_m or 0.0}
        if self.warmup_time_constant_s is not None:
            out["warmup_time_constant_s"] = self.warmup_time_constant_s
        return out

    def to_toml(self, preset: str = "urg-04lx-ug01", *, source: str = "") -> str:
        """A TOML document with a ``[lidar]`` section (the preset plus the fit).

        Args:
          preset: the preset the fit refines (its grid, range limits, beam).
          source: what was fitted (a path), for the header comment.

        Raises:
          ValueError: an unknown preset.
        """
        if preset not in PRESETS:
            raise ValueError(f"unknown LiDAR preset {preset!r}; valid presets: {', '.join(PRESETS)}")
        lines = ["# Sensor model fitted by `plantsim sensor fit`"
                 + (f" from {source}" if source else ""),
                 f"# {self.n_returns} returns ({self.n_outliers} outliers left out), "
                 f"RMS residual {self.rms_residual_m * 1000:.2f} mm.",
                 ("# Not separable in the recording (written as 0): "
                  + (", ".join(k for k, v in (("range_bias_rel", self.range_bias_rel),
                                              ("range_bias_dark_m", self.range_bias_dark_m),
                                              ("warmup_drift_m", self.warmup_drift_m)) if v is None)
                     or "none") + "."),
                 "", "[lidar]", f'preset = "{preset}"']
        for key, value in self.lidar_overrides().items():
            lines.append(f'{key} = "{value}"' if isinstance(value, str) else f"{key} = {value:.6g}")
        return "\n".join(lines) + "\n"


def _solve(X: np.ndarray, y: np.ndarray, w: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """Weighted least squares; returns the coefficients and the weighted SSE."""
    if w is not None:
        sw = np.sqrt(w)
        X, y = X * sw[:, None], y * sw
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    resid = y - X @ coef
    return coef, float(resid @ resid)


def _systematic(e, r, rho, t, *, fit_scale, fit_dark, fit_drift, tau=None):
    """Design matrix of the systematic model (drift column for one tau)."""
    cols = [np.ones_like(e)]
    if fit_scale:
        cols.append(r)
    if fit_dark:
        cols.append(1.0 - rho)
    if fit_drift:
        cols.append(np.exp(-t / tau))
    return np.stack(cols, axis=1)


def _drift_sse(e, r, rho, line, t_line, w, *, fit_scale, fit_dark) -> np.ndarray:
    """Weighted SSE of the systematic fit for every tau of :data:`TAU_GRID_S`.

    The drift column exp(-t/tau) is constant within a line, so the normal
    equations are assembled from per-line sums: O(n_lines) per tau.
    """
    base = [np.ones_like(e)] + ([r] if fit_scale else []) + ([1.0 - rho] if fit_dark else [])
    B = np.stack(base, axis=1)
    BtB = (B * w[:, None]).T @ B
    Bty = (B * w[:, None]).T @ e
    yty = float(np.sum(w * e * e))
    n_lines = len(t_line)
    # Per-line sums of w * base column and of w * e.
    line_wB = np.stack([np.bincount(line, weights=w * col, minlength=n_lines) for col in B.T], axis=1)
    line_w = line_wB[:, 0]
    line_we = np.bincount(line, weights=w * e, minlength=n_lines)
    k = B.shape[1]
    sse = np.empty(len(TAU_GRID_S))
    for i, tau in enumerate(TAU_GRID_S):
        E = np.exp(-t_line / tau)
        A = np.empty((k + 1, k + 1))
        A[:k, :k] = BtB
        A[:k, k] = A[k, :k] = E @ line_wB
        A[k, k] = (E * E) @ line_w
        rhs = np.append(Bty, E @ line_we)
        try:
            coef = np.linalg.solve(A, rhs)
        except np.linalg.LinAlgError:
            sse[i] = np.inf
            continue
        sse[i] = yty - coef @ rhs
    return sse


def fit_sensor(recording: FlatTargetRecording, *, edge_margin_m: float = 0.02) -> SensorFit:
    """Estimates the sensor's noise, bias and warm-up drift from a flat-target recording.

    Args:
      recording: ranges, beam angles, times and the target's geometry.
      edge_margin_m: beams whose hit lies within this of the plate's edges are
        left out (mixed pixels), metres.

    Returns:
      the fitted :class:`SensorFit`.

    Raises:
      ValueError: too few usable returns (fewer than 100 on the plate).
    """
    true, cos = recording.target.truth(recording.beam_angles_rad, edge_margin_m=edge_margin_m)
    use = np.isfinite(true) & np.isfinite(recording.range_m)
    n_use = int(use.sum())
    if n_use < 100:
        raise ValueError(f"only {n_use} returns lie on the plate (need at least 100): check the "
                         f"target geometry (distance, normal angle, half-width) against the recording")
    line = np.nonzero(use)[0]
    r = true[use]
    e = recording.range_m[use] - r
    rho = recording.target.reflectance[line]
    t = recording.time_since_power_on_s[line]
    r_eq2 = r ** 2 / np.maximum(rho * cos[use], 1e-9)

    fit_scale = np.ptp(recording.target.distance_m[np.unique(line)]) > 0.05
    fit_dark = np.ptp(rho) > 0.1
    keep = np.ones(len(e), dtype=bool)
    var = np.full(len(e), np.var(e))
    q2 = recording.range_resolution_m ** 2 / 12.0
    drift_possible = True
    tau = None
    for _ in range(3):
        w = 1.0 / var[keep]
        ek, rk, rhok, tk = e[keep], r[keep], rho[keep], t[keep]
        fit_drift = False
        if drift_possible:
            sse = _drift_sse(ek, rk, rhok, line[keep], recording.time_since_power_on_s, w,
                             fit_scale=fit_scale, fit_dark=fit_dark)
            i = int(np.argmin(sse))
            tau = float(TAU_GRID_S[i])
            if 0 < i < len(sse) - 1:  # parabola through the best three (in log tau)
                y0, y1, y2 = sse[i - 1], sse[i], sse[i + 1]
                den = y0 - 2 * y1 + y2
                if den > 0:
                    step = np.log(TAU_GRID_S[i + 1] / TAU_GRID_S[i])
                    tau = float(np.exp(np.log(tau) + 0.5 * step * (y0 - y2) / den))
            contrast = math.exp(-tk.min() / tau) - math.exp(-tk.max() / tau)
            fit_drift = contrast >= MIN_DRIFT_CONTRAST and 0 < i < len(sse) - 1
            if not fit_drift:
                drift_possible = False
                log.info("no warm-up drift separable in the recording (times %.0f-%.0f s since "
                         "power-on); record from power-on to fit it", tk.min(), tk.max())
        X = _systematic(ek, rk, rhok, tk, fit_scale=fit_scale, fit_dark=fit_dark,
                        fit_drift=fit_drift, tau=tau)
        coef, _ = _solve(X, ek, w)
        Xall = _systematic(e, r, rho, t, fit_scale=fit_scale, fit_dark=fit_dark,
                           fit_drift=fit_drift, tau=tau)
        resid = e - Xall @ coef
        # Noise: E[resid^2] = s0^2 + rel^2 r_eq^2 + q^2/12, weights 1/var^2.
        Z = np.stack([np.ones(len(e)), r_eq2], axis=1)
        y2 = resid ** 2 - q2
        vk = var[keep]
        (a, b), _ = _solve(Z[keep], y2[keep], 1.0 / vk ** 2)
        a, b = max(a, 0.0), max(b, 0.0)
        var = np.maximum(a + b * r_eq2, q2) + q2
        keep = np.abs(resid) <= OUTLIER_SIGMAS * np.sqrt(var)

    names = iter(coef)
    b0 = float(next(names))
    b_rel = float(next(names)) if fit_scale else None
    b_dark = float(next(names)) if fit_dark else None
    amp = float(next(names)) if fit_drift else None
    fitted = SensorFit(range_sigma_m=math.sqrt(a), range_sigma_rel=math.sqrt(b), range_bias_m=b0,
                       range_bias_rel=b_rel, range_bias_dark_m=b_dark, warmup_drift_m=amp,
                       warmup_time_constant_s=tau if fit_drift else None,
                       n_returns=int(keep.sum()), n_outliers=int((~keep).sum()),
                       rms_residual_m=float(np.sqrt(np.mean(resid[keep] ** 2))))
    log.info("sensor fit: %s", fitted)
    return fitted
