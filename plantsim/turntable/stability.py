"""One case of the numerical-stability matrix: run the servo, or stop with a clear error.

A case scales the default PID gains, sets the timestep, integrator, load
inertia and speed, and either runs a move and a constant-speed spin stably
(finite state, no MuJoCo warning, tracking error within bounds) or is stopped
by one of the simulator's own checks with a :class:`SimulationError` or a
``ValueError`` that names the cause and the fix. Anything else is a bug.
``scripts/stability_study.py`` runs the whole matrix; the tests run a subset.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from plantsim.turntable.dynamics import DEFAULT_SERVO, TurntableDynamics, TurntableSim, build_dynamic_scene
from plantsim.turntable.options import TurntableOptions
from plantsim.errors import SimulationError
from plantsim.rig.geometry import RigGeometry


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
    """

    outcome: str
    message: str = ""
    max_tracking_error_rad: float = math.nan
    final_error_rad: float = math.nan
    n_steps: int = 0


def run_case(*, gain_factor: float = 1.0, timestep_s: float = 1e-3, integrator: str = "implicitfast",
             load_inertia_kg_m2: float | None = None, rev_per_s: float = 0.1,
             duration_s: float = 0.6, max_steps: int = 20_000) -> CaseOutcome:
    """Runs one case: a 10 degree step, then a spin at ``rev_per_s``.

    Args:
      gain_factor: multiplies the default position P gain (I gain likewise
        when non-zero).
      timestep_s, integrator: the physics.
      load_inertia_kg_m2: the turntable body's inertia about its axis (plant
        and disk), or None for the disk's own.
      rev_per_s: spin speed.
      duration_s: rig time of each phase (capped at ``max_steps`` steps).
    """
    servo = dataclasses.replace(DEFAULT_SERVO, position_p_gain=DEFAULT_SERVO.position_p_gain * gain_factor,
                                position_i_gain=DEFAULT_SERVO.position_i_gain * gain_factor)
    try:
        dyn = TurntableDynamics(servo=servo, timestep_s=timestep_s, integrator=integrator)
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
    return CaseOutcome("ok", "", float(np.abs(tr.shaft_rad - tr.setpoint_rad).max()), float(final), sim.steps)
