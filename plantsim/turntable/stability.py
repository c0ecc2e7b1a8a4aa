"""One case of the numerical-stability study: run the servo, or stop with a clear error.

A case sets the servo (gains, I gain register, armature), the jitter (ripple,
torque noise, backlash), the timestep, integrator, load inertia and speed, and
either runs a 10-degree move and a constant-speed spin stably (every guard of
:class:`~plantsim.turntable.dynamics.TurntableSim` passed; its
:class:`~plantsim.turntable.dynamics.DynamicsDiagnostics` recorded) or is stopped
by one of the simulator's own checks with a :class:`SimulationError` or a
``ValueError`` that names the cause and the fix. Anything else is a bug.
``scripts/stability_study.py`` runs the matrix, the issue-14 cases and a seeded
random search; the tests run a subset.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from plantsim.errors import SimulationError
from plantsim.rig.geometry import RigGeometry
from plantsim.turntable.dynamics import (DEFAULT_SERVO, DynamicsDiagnostics, JitterConfig, TurntableDynamics,
                                         TurntableSim, build_dynamic_scene)
from plantsim.turntable.options import TurntableOptions


@dataclasses.dataclass(frozen=True)
class CaseOutcome:
    """What one case did.

    Attributes:
      outcome: "ok" (ran stably), "refused" (stopped before stepping: settings
        checked up front), "stopped" (a check during the run) or "error" (a
        ValueError from the settings, e.g. a speed the servo cannot reach).
      message: the error message, or "" when ok.
      max_tracking_error_rad: largest |shaft - setpoint| seen (NaN unless ok).
      final_error_rad: |shaft - goal| at the end of the move (NaN unless ok).
      n_steps: physics steps taken.
      diagnostics: :meth:`DynamicsDiagnostics.to_dict` of the run (empty unless ok).
    """

    outcome: str
    message: str = ""
    max_tracking_error_rad: float = math.nan
    final_error_rad: float = math.nan
    n_steps: int = 0
    diagnostics: dict = dataclasses.field(default_factory=dict)


def run_case(*, gain_factor: float = 1.0, timestep_s: float = 1e-3, integrator: str = "implicitfast",
             load_inertia_kg_m2: float | None = None, rev_per_s: float = 0.1,
             duration_s: float = 0.6, max_steps: int = 20_000, armature: float | None = None,
             i_gain_register: int | None = None, backlash_deg: float = 0.0, ripple_torque_nm: float = 0.0,
             torque_noise_nm: float = 0.0, torque_noise_period_s: float = 1e-3) -> CaseOutcome:
    """Runs one case: a 10 degree step, then a spin at ``rev_per_s``.

    Args:
      gain_factor: multiplies the default position P gain (I gain likewise
        when non-zero).
      timestep_s, integrator: the physics.
      load_inertia_kg_m2: the turntable body's inertia about its axis (plant
        and disk), or None for the disk's own.
      rev_per_s: spin speed.
      duration_s: rig time of each phase (capped at ``max_steps`` steps).
      armature: the servo's reflected rotor inertia, kg m^2 (None = XM430's).
      i_gain_register: "Position I Gain" register value (None = factory 0).
      backlash_deg, ripple_torque_nm, torque_noise_nm, torque_noise_period_s:
        the jitter (see :class:`JitterConfig`).
    """
    try:
        servo = dataclasses.replace(DEFAULT_SERVO, position_p_gain=DEFAULT_SERVO.position_p_gain * gain_factor,
                                    position_i_gain=DEFAULT_SERVO.position_i_gain * gain_factor)
        if armature is not None:
            servo = dataclasses.replace(servo, armature=armature)
        if i_gain_register is not None:
            servo = servo.with_registers({"Position I Gain": int(i_gain_register)})
        jitter = JitterConfig(backlash_deg=backlash_deg, ripple_torque_nm=ripple_torque_nm,
                              torque_noise_nm=torque_noise_nm, torque_noise_period_s=torque_noise_period_s)
        dyn = TurntableDynamics(servo=servo, jitter=jitter, timestep_s=timestep_s, integrator=integrator)
        TurntableOptions(mode="continuous", rpm=rev_per_s * 60, dynamics=dyn)
    except ValueError as exc:
        return CaseOutcome("error", str(exc))
    ds = build_dynamic_scene(RigGeometry(), None, dyn)
    if load_inertia_kg_m2 is not None:
        body = ds.scene.model.body("turntable").id
        ds.scene.model.body_inertia[body] = [load_inertia_kg_m2] * 3
    try:
        sim = TurntableSim(ds, np.random.default_rng(0))
    except SimulationError as exc:
        return CaseOutcome("refused", str(exc))
    n = max(1, min(max_steps, int(round(duration_s / timestep_s))))
    goal = math.radians(10)
    try:
        sim.command(goal)
        sim.advance(n)
        final = abs(sim.shaft_rad - goal)
        sim.command(goal + 1e3, profile_velocity_rad_s=rev_per_s * 2 * math.pi)
        sim.advance(n)
    except SimulationError as exc:
        return CaseOutcome("stopped", str(exc), n_steps=sim.steps)
    tr = sim.trajectory()
    diag = DynamicsDiagnostics.from_trajectory(tr, settle_tolerance_rad=dyn.settle_tolerance_rad)
    return CaseOutcome("ok", "", diag.max_tracking_error_rad, float(final), sim.steps, diag.to_dict())


# The issue-14 cases as run_case arguments (each at its extreme, as the issue ran it).
ISSUE_CASES = {
    "S1 armature 0, backlash 1 deg, 2 rpm": dict(armature=0.0, backlash_deg=1.0, rev_per_s=2 / 60),
    "S1 same, rk4": dict(armature=0.0, backlash_deg=1.0, rev_per_s=2 / 60, integrator="rk4"),
    "S2 backlash 1 deg": dict(backlash_deg=1.0),
    "S2 backlash 0.01 deg": dict(backlash_deg=0.01),
    "S3 I gain 16383, 5 rpm": dict(i_gain_register=16383, rev_per_s=5 / 60),
    "S3 I gain 8900, 5 rpm": dict(i_gain_register=8900, rev_per_s=5 / 60, duration_s=2.0),
    "S4 ripple, 5 rpm, dt 5e-3": dict(ripple_torque_nm=0.02, rev_per_s=5 / 60, timestep_s=5e-3),
    "C1 noise period 1e-9": dict(torque_noise_nm=0.01, torque_noise_period_s=1e-9),
    "C2 timestep 1e-9": dict(timestep_s=1e-9),
    "U1 40 rpm": dict(rev_per_s=40 / 60),
    "U1 30 rpm": dict(rev_per_s=30 / 60),
    "F1 weak P gain": dict(gain_factor=1 / 20, rev_per_s=1 / 60),
}


def random_cases(n: int, seed: int = 14) -> list[dict]:
    """A seeded adversarial search: ``n`` cases drawn over every setting's range.

    Log-uniform over the bounds the settings accept (or their extremes), with
    zero armature, backlash, ripple and noise each drawn often.
    """
    rng = np.random.default_rng(seed)

    def log_uniform(lo, hi):
        return float(10 ** rng.uniform(math.log10(lo), math.log10(hi)))

    def sometimes(value, p=0.5):
        return value if rng.random() < p else 0.0

    out = []
    for _ in range(n):
        out.append(dict(
            gain_factor=log_uniform(1e-3, 1e4), timestep_s=log_uniform(1e-5, 2e-2),
            integrator=str(rng.choice(["euler", "implicitfast", "rk4"])),
            load_inertia_kg_m2=log_uniform(1e-8, 1.0), rev_per_s=log_uniform(1 / 600, 0.8),
            armature=sometimes(log_uniform(1e-5, 0.2), 0.7),
            i_gain_register=int(sometimes(float(rng.integers(1, 16384)), 0.4)),
            backlash_deg=sometimes(log_uniform(1e-3, 10.0)),
            ripple_torque_nm=sometimes(log_uniform(1e-4, 0.5)),
            torque_noise_nm=sometimes(log_uniform(1e-4, 0.5)),
            torque_noise_period_s=log_uniform(1e-9, 0.1)))
    return out
