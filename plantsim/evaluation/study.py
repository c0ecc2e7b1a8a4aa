"""Error against run time: sweep scan settings over plants, measure every run.

A :class:`Sweep` is data: the plants, a grid of settings (each a name from
:data:`SETTINGS` and the values to try) and the fixed configuration the grid
overrides. :meth:`Sweep.runs` expands the grid (every plant x every combination);
:func:`run_study` runs them in parallel on the local cores (one process per
core, each casting on one thread), each run being :func:`plantsim.scan.pipeline.run_scan`
followed by :func:`plantsim.evaluate.evaluate_scan`. Every run gives one flat row:
its settings, wall time, CPU time, simulated rig time and every metric and trait
error; :func:`rows_to_csv` writes them, :func:`pareto_front` finds the runs no other
run beats on both error and time, :func:`plot_error_vs_time` draws them (one front
per plant and sensor: the ideal sensor is the reference, not a choice).

Wall time is the scan's own (load, build, cast, reconstruct), without the
evaluation; it is measured while other runs share the machine, so on a loaded
machine the CPU time of the run's process is the steadier figure.
"""

from __future__ import annotations

import concurrent.futures
import csv
import dataclasses
import io
import itertools
import logging
import math
import multiprocessing
import time
import types
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from plantsim._cores import usable_cores
from plantsim.scan.config import config_from_dict, merge
from plantsim.scan.plan import plan_scan
from plantsim.evaluation.evaluate import EvaluationOptions, evaluate_scan
from plantsim.resources import BUNDLED_PLANTS
from plantsim.sensor.spec import lidar_preset
from plantsim.validation import check_bool, check_int, check_optional, require_extra

logger = logging.getLogger(__name__)


def _base_lidar(base: Mapping[str, Any]):
    """The LiDAR a sweep's base configuration describes: its preset with the base's overrides."""
    lidar = dict(base.get("lidar", {}))
    return lidar_preset(lidar.pop("preset", "urg-04lx-ug01")).replace(**lidar)


def _n_beams(value: int, base: Mapping[str, Any]) -> dict:
    """Beams per line over the preset's unchanged field of view."""
    spec = _base_lidar(base)
    n = int(value)
    if n < 2:
        raise ValueError(f"n_beams must be at least 2 to span the field of view, got {value!r}")
    # The encoder's step grid no longer matches the beams: spread them over the
    # field of view's share of a turn instead (LidarSpec.beam_time_offsets_s).
    return {"lidar": {"n_beams": n, "angle_increment_deg": spec.fov_deg / (n - 1),
                      "steps_per_rev": None, "first_step": 0}}


def _range_noise_scale(value: float, base: Mapping[str, Any]) -> dict:
    """The preset's random range noise times ``value``: its floor and its power-law part
    both, so every return's standard deviation scales by ``value`` (a better or worse
    sensor of the same kind)."""
    k = float(value)
    if not math.isfinite(k) or k <= 0:
        raise ValueError(f"range_noise_scale must be a finite number > 0, got {value!r}; for no range noise "
                         "set [sensor_model] range_noise = false in the base configuration")
    spec = _base_lidar(base)
    return {"lidar": {"range_sigma_m": k * spec.range_sigma_m, "range_sigma_rel": k * spec.range_sigma_rel}}


@dataclasses.dataclass(frozen=True)
class Setting:
    """A setting a sweep can vary.

    Attributes:
        name: its name in a sweep, a CSV column and the command line.
        help: what it is, with its unit.
        overrides: value, base configuration -> configuration overrides (TOML layout).
        sensor_only: it changes only the realistic sensor model (an ideal run
            ignores it, so the sweep does not repeat ideal runs for it).
        mode_only: "step" or "continuous" when it applies to that scan mode only
            (blank in the other mode's runs, which are not repeated for it).
    """

    name: str
    help: str
    overrides: Callable[[Any, Mapping[str, Any]], dict]
    sensor_only: bool = False
    mode_only: str | None = None


def _at(section: str, key: str) -> Callable[[Any, Mapping[str, Any]], dict]:
    return lambda value, base: {section: {key: value}}


SETTINGS: dict[str, Setting] = {s.name: s for s in (
    Setting("mode", "scan mode: step (move, settle, take a line) or continuous (the table turns)",
            _at("turntable", "mode")),
    Setting("step_deg", "turntable step between scan lines, degrees", _at("scan", "step_deg"), mode_only="step"),
    Setting("n_beams", "beams per scan line over the preset's field of view", _n_beams),
    Setting("footprint_rings", "rings of sub-rays across a beam's footprint (0: 1 ray, 1: 7, 2: 19)",
            _at("sensor_model", "footprint_rings"), sensor_only=True),
    Setting("range_noise_scale", "the LiDAR preset's random range noise times this (0.25: a sensor four "
            "times quieter; the standard deviation of every return scales by it)", _range_noise_scale,
            sensor_only=True),
    Setting("timestep_s", "physics timestep of the turntable's servo, seconds (dynamic scans)",
            _at("turntable", "timestep_s")),
    Setting("rpm", "turntable speed of a continuous scan, revolutions per minute",
            _at("turntable", "rpm"), mode_only="continuous"),
    Setting("ideal", "perfect geometry (true) or the realistic sensor (false)",
            lambda value, base: {"ideal": bool(value)}),
    Setting("seed", "seed of the run's randomness", lambda value, base: {"seed": int(value)}),
)}


def plant_overrides(plant: str) -> dict:
    """A bundled plant's name or a mesh path as configuration overrides."""
    if plant in BUNDLED_PLANTS:
        return {"plant": {"bundled": plant, "mesh": None}}
    if not Path(plant).is_file():
        raise FileNotFoundError(f"plant must be a bundled plant ({', '.join(BUNDLED_PLANTS)}) or "
                                f"a mesh file; not found: {plant}")
    return {"plant": {"mesh": str(plant)}}


@dataclasses.dataclass(frozen=True, kw_only=True)
class Sweep:
    """Which runs a study makes.

    Attributes:
        plants: bundled plant names or mesh paths (at least one).
        grid: (setting name, values) pairs, in the order the CSV lists them; every
            combination is run.
        base: the fixed configuration, nested as in a TOML file (``scan``,
            ``lidar``, ``turntable``, ...); the grid's values override it. Kept as a
            read-only mapping (None: empty).
        evaluation: how each run is measured.
    """

    plants: tuple[str, ...]
    grid: tuple[tuple[str, tuple], ...] = ()
    base: Mapping[str, Any] | None = None
    evaluation: EvaluationOptions = EvaluationOptions()

    def __post_init__(self) -> None:
        object.__setattr__(self, "plants", tuple(self.plants))
        object.__setattr__(self, "grid", tuple((name, tuple(values)) for name, values in self.grid))
        object.__setattr__(self, "base", types.MappingProxyType(dict(self.base or {})))
        if not self.plants:
            raise ValueError("plants must name at least one plant, got none")
        names = [name for name, _ in self.grid]
        for name, values in self.grid:
            if name not in SETTINGS:
                raise ValueError(f"unknown setting {name!r} in grid; valid settings: {', '.join(SETTINGS)}")
            if not values:
                raise ValueError(f"setting {name!r} has no values to try")
        if len(set(names)) != len(names):
            raise ValueError(f"grid names a setting twice: {names}")
        for name, values in self.grid:  # a bad value fails here, not after an hour of runs
            for value in values:
                SETTINGS[name].overrides(value, self.base)
        ideals = {bool(v) for v in dict(self.grid).get("ideal", (self.base.get("ideal", False),))}
        sensor_only = [name for name in names if SETTINGS[name].sensor_only]
        if sensor_only and ideals == {True}:
            raise ValueError(f"{', '.join(sensor_only)} change{'s' if len(sensor_only) == 1 else ''} the realistic "
                             "sensor only, and every run is ideal; add realistic runs "
                             "(plantsim study --ideal-and-realistic, or ideal = false) or drop "
                             f"{'it' if len(sensor_only) == 1 else 'them'}")
        if "range_noise_scale" in names and self.base.get("sensor_model", {}).get("range_noise") is False:
            raise ValueError("range_noise_scale scales the range noise, which the base configuration turns off "
                             "([sensor_model] range_noise = false); drop one of them")
        turntable = self.base.get("turntable", {})
        modes = set(dict(self.grid).get("mode", (turntable.get("mode", "step"),)))
        if "rpm" in names and "continuous" not in modes:
            raise ValueError("rpm applies to continuous scans only; set turntable mode = \"continuous\" "
                             "(plantsim study --mode continuous)")
        if "timestep_s" in names and "continuous" not in modes \
                and turntable.get("physics", "auto") != "dynamic":
            raise ValueError("timestep_s applies to scans with the servo's physics only; use "
                             "--mode continuous or --physics dynamic")

    @property
    def setting_names(self) -> tuple[str, ...]:
        """The swept settings, with ``ideal`` always among them (it changes every figure)."""
        names = tuple(name for name, _ in self.grid)
        return names if "ideal" in names else names + ("ideal",)

    def runs(self) -> list[dict[str, Any]]:
        """Every run: ``{"plant": ..., setting: value, ...}``, plants outermost.

        Sensor-only settings are blank (None) in ideal runs, and the repeats this
        makes are dropped.
        """
        names = [name for name, _ in self.grid]
        out, seen = [], set()
        for plant in self.plants:
            for values in itertools.product(*(v for _, v in self.grid)):
                run = {"plant": plant, **dict(zip(names, values))}
                run.setdefault("ideal", bool(self.base.get("ideal", False)))
                if run["ideal"]:
                    run.update({n: None for n in names if SETTINGS[n].sensor_only})
                mode = run.get("mode") or self.base.get("turntable", {}).get("mode", "step")
                run.update({n: None for n in names if SETTINGS[n].mode_only not in (None, mode)})
                key = tuple(sorted((k, repr(v)) for k, v in run.items()))
                if key not in seen:
                    seen.add(key)
                    out.append(run)
        return out

    def config_data(self, run: Mapping[str, Any]) -> dict:
        """The nested configuration (TOML layout; None where a value is unset) of one
        run, casting on one thread."""
        data = merge(dict(self.base), plant_overrides(run["plant"]))
        for name, value in run.items():
            if name != "plant" and value is not None:
                data = merge(data, SETTINGS[name].overrides(value, data))
        return {**data, "threads": 1}


# --------------------------------------------------------------------------
# one run
# --------------------------------------------------------------------------
METRIC_COLUMNS = ("median", "p95", "p99", "max", "mean", "rms", "mesh_to_cloud_mean",
                  "mesh_to_cloud_p95", "chamfer", "coverage")
SCAN_PHASES = ("load_mesh", "build_scene", "turntable", "scan", "reconstruct")


def run_one(run: Mapping[str, Any], config_data: Mapping[str, Any],
            evaluation: EvaluationOptions = EvaluationOptions()) -> dict[str, Any]:
    """Scans and evaluates one run; returns its CSV row (see :func:`run_study`).

    A run that fails gives a row with its settings and ``error`` (the message),
    so that one bad combination does not lose the others.
    """
    from plantsim.scan.pipeline import run_scan, simulated_rig_time_s

    row: dict[str, Any] = dict(run)
    try:
        cpu0 = time.process_time()
        result = run_scan(config_from_dict(dict(config_data)))
        cpu_scan = time.process_time() - cpu0
        ev = evaluate_scan(result, options=evaluation)
    except Exception as exc:  # reported in the row: the study goes on
        logger.warning("run %s failed: %s", dict(run), exc)
        row["error"] = f"{type(exc).__name__}: {exc}"
        return row
    plan = result.plan
    row.update({
        # What was actually simulated, part by part (not what the settings might suggest).
        "sensor": plan.sensor, "turntable_motion": plan.motion, "mode": plan.mode, "angle_mode": plan.angle_mode,
        "wall_time_s": sum(result.timings_s.get(k, 0.0) for k in SCAN_PHASES),
        "cpu_time_s": cpu_scan,
        "simulated_rig_time_s": simulated_rig_time_s(result),
        "evaluate_time_s": ev.time_s,
        "n_lines": result.raw.n_lines,
        "n_beams_per_line": result.raw.n_beams,
        "points": len(result.cloud),
        "plant_points": ev.n_points,
    })
    # What the turntable did (dynamic scans: tracking, play, settle times; every simulated scan:
    # how far the plant's points moved for the believed-minus-true angle).
    for key, value in result.diagnostics.items():
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            row[f"turntable_{key}"] = value
    for key, value in result.diagnostics.get("angle_error_plant", {}).items():
        row[f"angle_error_{key}"] = value
    if ev.metrics is not None:
        row.update({f"{k}_m" if k != "coverage" else k: getattr(ev.metrics, k) for k in METRIC_COLUMNS})
    if ev.traits is not None:
        row["n_stems_found"], row["n_stems_true"] = ev.traits.n_stems
        for e in ev.traits.errors:
            if e.trait.startswith("stem["):
                continue  # per-stem errors stay in a scan's sidecar; the CSV keeps aggregates
            row[f"{e.trait}_estimate"] = e.estimate
            row[f"{e.trait}_reference"] = e.reference
            row[f"{e.trait}_rel_error"] = e.relative_error
    row["error"] = ""
    return row


def _run_one_remote(run: Mapping[str, Any], config_data: Mapping[str, Any],
                    evaluation: EvaluationOptions, mesh: tuple[str, bytes] | None,
                    traits: tuple[str, bytes] | None) -> dict[str, Any]:
    """:func:`run_one` on a worker that may not see this machine's files.

    ``mesh`` and ``traits`` are (file name, bytes) sent along: written to a
    temporary folder on the worker, and the configuration pointed at it.
    """
    import tempfile

    if mesh is None:
        return run_one(run, config_data, evaluation)
    with tempfile.TemporaryDirectory(prefix="plantsim-run-") as folder:
        path = Path(folder) / mesh[0]
        path.write_bytes(mesh[1])
        if traits is not None:
            (Path(folder) / traits[0]).write_bytes(traits[1])
        data = merge(dict(config_data), {"plant": {"mesh": str(path)}})
        return run_one(run, data, evaluation)


def _mesh_payload(data: Mapping[str, Any]) -> tuple[tuple[str, bytes] | None, tuple[str, bytes] | None]:
    from plantsim.evaluation.evaluate import truth_traits_path

    mesh = (data.get("plant") or {}).get("mesh")
    if not mesh:
        return None, None  # a bundled plant: every worker has it
    path = Path(mesh)
    truth = truth_traits_path(path)
    return (path.name, path.read_bytes()), (
        (truth.name, truth.read_bytes()) if truth is not None else None)


def run_study(sweep: Sweep, *, max_workers: int | None = None,
              progress: Callable[[int, int, dict], None] | None = None,
              executor: concurrent.futures.Executor | None = None,
              send_meshes: bool = False,
              threads_per_run: int | None = None) -> list[dict[str, Any]]:
    """Runs every run of a sweep, in parallel, and returns the rows in run order.

    Every configuration is built (and so validated) before any run starts.

    Args:
        sweep: the runs.
        max_workers: processes (None: one per available core; 1 runs in this
            process, one after the other). Ignored with ``executor``.
        progress: called with (runs done, runs total, the finished row).
        executor: where the runs go instead of local processes: any
            ``concurrent.futures.Executor``, e.g. a Dask cluster's
            ``distributed.Client(address).get_executor()`` (see
            :func:`dask_executor` and docs/cluster.md). It is not shut down.
            Each run is a ``run_one`` call, so the rows are those of a local run.
        send_meshes: send each mesh file (and its exact-traits JSON) with its
            runs, for workers that do not share this machine's files; False:
            workers read the mesh paths themselves (a shared file system).
        threads_per_run: ray-casting threads of each run (the ``threads``
            setting; None: what the configuration says, else all the
            worker's cores). Set it to a worker's cores / runs per worker.

    Returns:
        One dict per run: ``run`` (index), ``plant``, the swept settings, then
        ``wall_time_s``, ``cpu_time_s``, ``simulated_rig_time_s``,
        ``evaluate_time_s``, counts, the metrics (metres; coverage a share),
        ``<trait>_estimate``/``_reference``/``_rel_error`` when the plant's exact
        traits are known, and ``error`` ("" or why the run failed).

    Raises:
        ValueError: a configuration the grid makes is invalid, or sets what its run's parts
            would not use (:func:`plantsim.scan.plan.plan_scan`); nothing is run.
    """
    if max_workers is not None and (not isinstance(max_workers, int) or max_workers < 1):
        raise ValueError(f"max_workers must be a positive integer or None, got {max_workers!r}")
    check_bool("run_study", "send_meshes", send_meshes)
    check_optional(check_int, "run_study", "threads_per_run", threads_per_run, minimum=1)
    runs = sweep.runs()
    datas = []
    for i, run in enumerate(runs):
        data = sweep.config_data(run)
        if threads_per_run is not None:
            data = merge(data, {"threads": threads_per_run})
        try:
            # The plan too: a setting the run's parts would not use is refused now, not
            # as an error row after the runs before it.
            plan_scan(config_from_dict(data))
        except ValueError as exc:
            raise ValueError(f"run {i} ({run}) is not a valid configuration: {exc}") from exc
        datas.append(data)
    workers = min(max_workers or usable_cores(), len(runs))
    rows: list[dict[str, Any] | None] = [None] * len(runs)

    def done(i: int, row: dict) -> None:
        rows[i] = {"run": i, **row}
        if progress is not None:
            progress(sum(r is not None for r in rows), len(runs), rows[i])

    if executor is not None:
        order = sorted(range(len(runs)), key=lambda i: -_cost(runs[i]))
        payloads = {}
        futures = {}
        for i in order:
            mesh = (datas[i].get("plant") or {}).get("mesh")
            if send_meshes and mesh not in payloads:
                payloads[mesh] = _mesh_payload(datas[i])
            sent = payloads.get(mesh, (None, None)) if send_meshes else (None, None)
            futures[executor.submit(_run_one_remote, runs[i], datas[i], sweep.evaluation,
                                    *sent)] = i
        for future in concurrent.futures.as_completed(futures):
            done(futures[future], future.result())
    elif workers <= 1:
        for i, (run, data) in enumerate(zip(runs, datas)):
            done(i, run_one(run, data, sweep.evaluation))
    else:
        # Spawned workers: no state is shared with this process (MuJoCo, BLAS threads).
        context = multiprocessing.get_context("spawn")
        with concurrent.futures.ProcessPoolExecutor(max_workers=workers, mp_context=context) as pool:
            # The slowest runs (finest steps) first, so that no core idles at the end.
            order = sorted(range(len(runs)), key=lambda i: -_cost(runs[i]))
            futures = {pool.submit(run_one, runs[i], datas[i], sweep.evaluation): i for i in order}
            for future in concurrent.futures.as_completed(futures):
                done(futures[future], future.result())
    return rows  # type: ignore[return-value]


def dask_executor(scheduler: str, *, timeout_s: float = 30.0):
    """A ``concurrent.futures`` executor on a Dask distributed cluster.

    Args:
        scheduler: the scheduler's address, e.g. ``tcp://10.0.0.5:8786``; or a
            ``distributed.Client`` (e.g. of a ``LocalCluster``) to use as is.
        timeout_s: how long to wait for the scheduler.

    Returns:
        (executor, client): close the client when done.

    Raises:
        MissingExtraError: dask.distributed is not installed (names the extra).
        OSError: the scheduler cannot be reached (the address is in the message).
    """
    require_extra("distributed", "cluster", "running a study on a Dask cluster")
    import distributed

    if isinstance(scheduler, distributed.Client):
        client = scheduler
    else:
        try:
            client = distributed.Client(scheduler, timeout=timeout_s)
        except (OSError, TimeoutError) as exc:
            raise OSError(f"cannot reach the Dask scheduler at {scheduler}: {exc}") from exc
    # pure=False: two runs with equal arguments (repeats) are both run.
    return client.get_executor(pure=False), client


def _cost(run: Mapping[str, Any]) -> float:
    """A rough relative cost, to start the slow runs first."""
    cost = 1.0 / float(run.get("step_deg") or 1.0)
    if not run.get("ideal"):
        cost *= 3 * (1 + 3 * (run.get("footprint_rings") or 0))
    return cost * float(run.get("n_beams") or 683)


# --------------------------------------------------------------------------
# the results
# --------------------------------------------------------------------------
def pareto_front(errors: Sequence[float], times: Sequence[float]) -> np.ndarray:
    """Which runs no other run beats on both error and time (both minimised).

    A run is dominated when another has an error and a time no larger, and one of
    them smaller. Runs with a NaN error or time are never on the front; equal
    runs are all on it.

    Args:
        errors: (n,) the error of each run.
        times: (n,) the time of each run.

    Returns:
        (n,) bool: True on the front.

    Raises:
        ValueError: when the two lengths differ.
    """
    e = np.asarray(errors, dtype=np.float64).reshape(-1)
    t = np.asarray(times, dtype=np.float64).reshape(-1)
    if e.shape != t.shape:
        raise ValueError(f"errors and times must have the same length, got {e.size} and {t.size}")
    valid = np.isfinite(e) & np.isfinite(t)
    front = np.zeros(e.size, dtype=bool)
    idx = np.flatnonzero(valid)
    # Sweep by time (then error): a run is on the front when its error is below
    # every error seen at a strictly smaller time, or ties the best at its time.
    order = idx[np.lexsort((e[idx], t[idx]))]
    best = math.inf
    k = 0
    while k < order.size:
        same_t = order[t[order] == t[order[k]]]
        lowest = e[same_t].min()
        if lowest < best:
            front[same_t[e[same_t] == lowest]] = True
            best = lowest
        k += same_t.size
    return front


def _columns(rows: Iterable[Mapping[str, Any]]) -> list[str]:
    cols: list[str] = []
    for row in rows:
        cols.extend(k for k in row if k not in cols)
    if "error" in cols:  # the failure message goes last, where it is easy to read
        cols.remove("error")
        cols.append("error")
    return cols


def _cell(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return "" if math.isnan(value) else f"{value:.9g}"
    return str(value)


def rows_to_csv(rows: Sequence[Mapping[str, Any]]) -> str:
    """The rows as CSV text: a header of every column in first-seen order; blank
    where a row lacks a column or holds None/NaN; floats with 9 significant digits."""
    cols = _columns(rows)
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(cols)
    for row in rows:
        writer.writerow([_cell(row.get(c)) for c in cols])
    return out.getvalue()


def read_csv_rows(text: str) -> list[dict[str, Any]]:
    """CSV text from :func:`rows_to_csv` back into rows (numbers as float, blanks as None)."""
    rows = []
    for raw in csv.DictReader(io.StringIO(text)):
        row: dict[str, Any] = {}
        for key, value in raw.items():
            if value == "":
                row[key] = None
            elif value in ("True", "False"):
                row[key] = value == "True"
            else:
                try:
                    row[key] = float(value)
                except ValueError:
                    row[key] = value
        rows.append(row)
    return rows


def _series_label(row: Mapping[str, Any], names: Sequence[str]) -> str:
    parts = [str(Path(str(row["plant"])).stem)]
    parts.append("ideal" if row.get("ideal") else "realistic")
    for n in names:
        if n not in ("step_deg", "ideal", "plant") and row.get(n) is not None:
            parts.append(f"{n} {row[n]:g}" if isinstance(row[n], float) else f"{n} {row[n]}")
    return ", ".join(parts)


def _minor_label(value: float, _position: Any) -> str:
    """Labels the 2 and 5 of each decade on a log axis, as plain numbers."""
    if not value > 0:
        return ""
    lead = value / 10 ** math.floor(math.log10(value) + 1e-9)
    return f"{value:g}" if round(lead, 6) in (2.0, 5.0) else ""


def plot_error_vs_time(rows: Sequence[Mapping[str, Any]], *, error: str = "chamfer_m",
                       time: str = "wall_time_s", setting_names: Sequence[str] = ("step_deg",),
                       title: str | None = None) -> bytes:
    """A PNG of error against run time, one series per plant and setting
    combination, each point labelled with its step; the Pareto front of each plant
    and sensor (ideal or realistic) is ringed and joined.

    Args:
        rows: study rows (failed runs are left out).
        error: the column on the y axis (metres are shown in mm).
        time: the column on the x axis (seconds, log scale).
        setting_names: the swept settings (they name the series).
        title: the figure's title.

    Returns:
        The PNG's bytes.

    Raises:
        ValueError: when no run has both columns.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    ok = [r for r in rows if not r.get("error") and r.get(error) is not None and r.get(time) is not None]
    if not ok:
        raise ValueError(f"no run has both {error!r} and {time!r} to plot")
    scale, unit = (1e3, " [mm]") if error.endswith("_m") else (1.0, "")
    e = np.array([float(r[error]) for r in ok]) * scale
    t = np.array([float(r[time]) for r in ok])
    # One front per plant and sensor: the ideal sensor is a reference, not a
    # setting a rig can choose, so it must not push every realistic run off the front.
    groups = np.array([f"{r['plant']}|{bool(r.get('ideal'))}" for r in ok])
    front = np.zeros(len(ok), dtype=bool)
    for group in dict.fromkeys(groups):
        mine = np.flatnonzero(groups == group)
        front[mine] = pareto_front(e[mine], t[mine])
    fig, ax = plt.subplots(figsize=(7.5, 5.0), dpi=120)
    series: dict[str, list[int]] = {}
    for i, r in enumerate(ok):
        series.setdefault(_series_label(r, setting_names), []).append(i)
    for label, members in series.items():
        members = sorted(members, key=lambda i: t[i])
        ax.plot(t[members], e[members], marker="o", linewidth=1, label=label)
        for i in members:
            if ok[i].get("step_deg") is not None:
                ax.annotate(f"{float(ok[i]['step_deg']):g}°", (t[i], e[i]), textcoords="offset points",
                            xytext=(4, 4), fontsize=7)
    for k, group in enumerate(dict.fromkeys(groups)):
        f = np.flatnonzero(front & (groups == group))
        f = f[np.argsort(t[f])]
        ax.plot(t[f], e[f], linestyle="--", color="black", linewidth=1, zorder=0)
        ax.scatter(t[f], e[f], s=140, facecolors="none", edgecolors="black", linewidths=1.2,
                   label="Pareto front of each sensor (min error, min time)" if k == 0 else None)
    ax.set_xscale("log")
    if np.all(e[np.isfinite(e)] > 0):
        ax.set_yscale("log")
    for axis in (ax.xaxis, ax.yaxis):  # 0.2, not 2 x 10^-1
        axis.set_major_formatter(matplotlib.ticker.FuncFormatter(lambda v, _: f"{v:g}"))
        axis.set_minor_formatter(matplotlib.ticker.FuncFormatter(_minor_label))
    ax.set_xlabel(time.replace("_s", "") .replace("_", " ") + " [s]")
    ax.set_ylabel(error.removesuffix("_m").replace("_", " ") + unit)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    if title:
        ax.set_title(title, fontsize=10)
    fig.tight_layout()
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png")
    plt.close(fig)
    return buffer.getvalue()
