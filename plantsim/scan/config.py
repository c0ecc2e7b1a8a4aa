"""A scan's whole configuration: plant, sensor, rig, schedule, output.

Every option can come from a TOML file (sections ``[plant]``, ``[lidar]``,
``[rig]``, ``[scan]``, ``[output]``, ``[sensor_model]``, ``[turntable]``,
``[range_filter]``) and from
the command line, which wins.
The resolved configuration goes into every output's sidecar JSON.
"""

from __future__ import annotations

import dataclasses
import math
import os
import sys
from pathlib import Path
from typing import Any

from plantsim.turntable.options import TurntableOptions, turntable_options_from_dict
from plantsim.errors import ConfigError
from plantsim.validation import check_bool, check_int, check_number, check_optional, check_path, check_str
from plantsim.plant.mesh import PLACEMENTS, UNITS_TO_M
from plantsim.rig.geometry import RigGeometry
from plantsim.scan.schedule import StepScan
from plantsim.sensor.spec import PRESETS, LidarSpec, lidar_preset
from plantsim.sensor.casting import BACKENDS
from plantsim.sensor.model import SensorModel


@dataclasses.dataclass(frozen=True, kw_only=True)
class PlantOptions:
    """Which plant, and how to read and place it.

    Attributes:
      mesh: path of an STL/OBJ/PLY file, or None for the bundled maize.
      bundled: name of a bundled plant used when ``mesh`` is None.
      units: the file's unit: "m", "cm", "mm".
      up: the file's up axis: "x", "y", "z".
      placement: "base", "bbox" or "none" (see :func:`plantsim.mesh.load_plant`).
      T_turntable_mesh: explicit rigid placement, 4x4 row-major nested lists, or None.
      base_point: a point put on the axis at the disk top, x, y, z in the mesh
        file's own units and axes, instead of the stem base found (a pot's centre,
        the main culm of a clump of tillers); with ``placement`` "base" only, not
        with ``T_turntable_mesh`` (see :func:`plantsim.plant.mesh.load_plant`).
      areal_density_kg_m2: mass per area for the plant's inertial.
    """

    mesh: str | None = None
    bundled: str = "maize"
    units: str = "m"
    up: str = "z"
    placement: str = "base"
    T_turntable_mesh: tuple | None = None
    base_point: tuple | None = None
    areal_density_kg_m2: float = 0.3

    def __post_init__(self):
        check_optional(check_path, "plant", "mesh", self.mesh)
        check_str("plant", "bundled", self.bundled)
        if self.units not in UNITS_TO_M:
            raise ValueError(f"units must be one of {', '.join(UNITS_TO_M)}, got {self.units!r}")
        if self.up not in ("x", "y", "z"):
            raise ValueError(f"up must be one of x, y, z, got {self.up!r}")
        if self.placement not in PLACEMENTS:
            raise ValueError(f"placement must be one of {', '.join(PLACEMENTS)}, got {self.placement!r}")
        if self.base_point is not None:
            if not (isinstance(self.base_point, (tuple, list)) and len(self.base_point) == 3
                    and all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)
                            for x in self.base_point)):
                raise ValueError(f"base_point must be 3 finite numbers (x, y, z in the mesh file's units and "
                                 f"axes), got {self.base_point!r}")
            object.__setattr__(self, "base_point", tuple(float(x) for x in self.base_point))
            if self.T_turntable_mesh is not None or self.placement != "base":
                other = "T_turntable_mesh" if self.T_turntable_mesh is not None else f"placement = {self.placement!r}"
                raise ValueError(f"base_point and {other} both place the plant: remove one (base_point goes "
                                 "with placement = \"base\")")
        if not (isinstance(self.areal_density_kg_m2, (int, float))
                and math.isfinite(self.areal_density_kg_m2) and self.areal_density_kg_m2 > 0):
            raise ValueError(f"areal_density_kg_m2 must be a positive number, got {self.areal_density_kg_m2!r}")


@dataclasses.dataclass(frozen=True, kw_only=True)
class OutputOptions:
    """Where and what to write.

    Attributes:
      path: the point cloud; its extension picks the format (.las .ply .pcd .txt .xyz).
      plant_only: write only points on the plant.
      raw: a folder to write the raw record to, as a ROS 2 bag (MCAP storage),
        or None.
    """

    path: str = "scan.las"
    plant_only: bool = False
    raw: str | None = None

    def __post_init__(self):
        check_path("output", "path", self.path)
        check_bool("output", "plant_only", self.plant_only)
        check_optional(check_path, "output", "raw", self.raw)


@dataclasses.dataclass(frozen=True, kw_only=True)
class RangeFilter:
    """Settings of the range-image filter (``[range_filter]``; method in :mod:`plantsim.cloud.denoise`).

    Attributes:
      enabled: filter the ranges before the points are made.
      half_lines: window half-size across lines (turntable angles), lines.
      half_beams: window half-size along the fan, beams.
      gate_sigma: neighbours within this many noise sigmas of the window's median
        range are the beam's surface.
      min_support: fewest neighbours (the beam itself included) a fit needs; a beam with
        fewer keeps its range.
      sigma_m: the range noise, metres; None measures it on the scan.
    """

    enabled: bool = False
    half_lines: int = 3
    half_beams: int = 3
    gate_sigma: float = 2.5
    min_support: int = 6
    sigma_m: float | None = None

    def __post_init__(self) -> None:
        check_bool("range_filter", "enabled", self.enabled)
        check_int("range_filter", "half_lines", self.half_lines, minimum=0, maximum=20)
        check_int("range_filter", "half_beams", self.half_beams, minimum=0, maximum=20)
        if self.half_lines == 0 and self.half_beams == 0:
            raise ValueError("range_filter.half_lines and half_beams are both 0: the window is one beam and "
                             "filters nothing; make one of them at least 1")
        check_number("range_filter", "gate_sigma", self.gate_sigma, minimum=0.0, strict_minimum=True)
        window = (2 * self.half_lines + 1) * (2 * self.half_beams + 1)
        check_int("range_filter", "min_support", self.min_support, minimum=3, maximum=window)
        check_optional(check_number, "range_filter", "sigma_m", self.sigma_m, minimum=0.0, unit="m")


@dataclasses.dataclass(frozen=True, kw_only=True)
class RunConfig:
    """Everything a scan run needs.

    Attributes:
      seed: seed of the run's one ``numpy.random.Generator`` (all randomness).
      ideal: turn off every imperfection (perfect geometry): one ray per
        beam, exact ranges, no intensity, no dropouts.
      threads: ray-casting threads (None: all cores).
      turntable: how the table moves (mode, servo, jitter, encoder); see
        :class:`plantsim.dynamic_scan.TurntableOptions`.
      sensor_model: the sensor imperfections and reflectances of a
        non-ideal run (``[sensor_model]``).
      sensor: "realistic" (default) or "ideal": the LiDAR alone.
      range_filter: denoise the ranges in the range image before the points are made
        (:mod:`plantsim.cloud.denoise`); the raw record keeps the sensor's ranges.
      caster: the ray-casting backend: "auto" (Embree when installed, else
        MuJoCo), "embree" or "mujoco" (the reference; same hits, slower).
      explicit: dotted paths of the settings the user gave (filled by
        :func:`config_from_dict`); the plan refuses given settings the chosen
        parts would not use.
    """

    plant: PlantOptions = PlantOptions()
    lidar: LidarSpec = PRESETS["urg-04lx-ug01"]
    rig: RigGeometry = RigGeometry()
    scan: StepScan = StepScan()
    output: OutputOptions = OutputOptions()
    seed: int = 0
    ideal: bool = False
    sensor: str = "realistic"
    caster: str = "auto"
    threads: int | None = None
    turntable: TurntableOptions = TurntableOptions()
    sensor_model: SensorModel = SensorModel()
    range_filter: RangeFilter = RangeFilter()
    explicit: frozenset = frozenset()

    def __post_init__(self):
        for name, cls in (("plant", PlantOptions), ("lidar", LidarSpec), ("rig", RigGeometry), ("scan", StepScan),
                          ("output", OutputOptions), ("turntable", TurntableOptions), ("sensor_model", SensorModel),
                          ("range_filter", RangeFilter)):
            if not isinstance(getattr(self, name), cls):
                raise TypeError(f"RunConfig.{name} must be a plantsim.{cls.__name__}, got "
                                f"{type(getattr(self, name)).__name__}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise ValueError(f"seed must be a non-negative integer, got {self.seed!r}")
        if self.threads is not None and (isinstance(self.threads, bool) or not isinstance(self.threads, int)
                                         or self.threads < 1):
            raise ValueError(f"threads must be a positive integer, got {self.threads!r}")
        if not isinstance(self.ideal, bool):
            raise ValueError(f"ideal must be true or false, got {self.ideal!r}")
        if self.sensor not in SENSORS:
            raise ValueError(f"sensor must be one of {', '.join(SENSORS)}, got {self.sensor!r}")
        if self.caster not in BACKENDS:
            raise ValueError(f"caster must be one of {', '.join(BACKENDS)}, got {self.caster!r}")
        if not isinstance(self.output.plant_only, bool):
            raise ValueError(f"plant_only must be true or false, got {self.output.plant_only!r}")
        object.__setattr__(self, "explicit", frozenset(self.explicit))

    def replace(self, **changes) -> "RunConfig":
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict:
        """The resolved configuration as plain JSON-able data."""
        return {
            "plant": dataclasses.asdict(self.plant),
            "lidar": dataclasses.asdict(self.lidar),
            "rig": dataclasses.asdict(self.rig),
            "scan": dataclasses.asdict(self.scan),
            "output": dataclasses.asdict(self.output),
            "seed": self.seed,
            "ideal": self.ideal,
            "sensor": self.sensor,
            "caster": self.caster,
            "threads": self.threads,
            "turntable": dataclasses.asdict(self.turntable),
            "sensor_model": dataclasses.asdict(self.sensor_model),
            "range_filter": dataclasses.asdict(self.range_filter),
        }


_SECTIONS = {"plant": PlantOptions, "rig": RigGeometry, "scan": StepScan, "output": OutputOptions,
             "sensor_model": SensorModel, "range_filter": RangeFilter}
_TOP_LEVEL = ("seed", "ideal", "sensor", "caster", "threads")
SENSORS = ("ideal", "realistic")


def given_keys(data: dict[str, Any], prefix: str = "") -> set[str]:
    """Dotted paths of every value in nested plain data (``turntable.jitter.backlash_deg``)."""
    keys = set()
    for key, value in data.items():
        path = f"{prefix}{key}"
        if isinstance(value, dict):
            keys |= given_keys(value, path + ".")
        else:
            keys.add(path)
    return keys


def _known(cls) -> list[str]:
    return [f.name for f in dataclasses.fields(cls)]


def _build(cls, values: dict, where: str):
    unknown = sorted(set(values) - set(_known(cls)))
    if unknown:
        raise ConfigError(f"unknown key(s) {', '.join(unknown)} in [{where}]; valid keys: "
                          f"{', '.join(_known(cls))}")
    try:
        return cls(**values)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"[{where}] {exc}") from exc


def config_from_dict(data: dict[str, Any], *, base_dir: str | os.PathLike | None = None) -> RunConfig:
    """Builds a :class:`RunConfig` from nested plain data (a parsed TOML file).

    Relative paths of ``plant.mesh`` are taken relative to ``base_dir``.
    """
    unknown = sorted(set(data) - set(_SECTIONS) - {"lidar", "turntable"} - set(_TOP_LEVEL))
    if unknown:
        raise ConfigError(f"unknown key(s) or section(s) {', '.join(unknown)}; valid: "
                          f"{', '.join(list(_SECTIONS) + ['lidar', 'turntable'] + list(_TOP_LEVEL))}")
    for name in list(_SECTIONS) + ["lidar", "turntable"]:
        if name in data and not isinstance(data[name], dict):
            raise ConfigError(f"{name} must be a [{name}] section (a TOML table), got {data[name]!r}; "
                              f"write it as [{name}] with its keys below")
    parts = {}
    for name, cls in _SECTIONS.items():
        values = dict(data.get(name, {}))
        if name == "plant" and values.get("mesh") and base_dir is not None:
            values["mesh"] = str(Path(base_dir) / Path(values["mesh"]).expanduser())
        if name == "plant" and values.get("T_turntable_mesh") is not None:
            values["T_turntable_mesh"] = tuple(tuple(float(x) for x in row)
                                               for row in values["T_turntable_mesh"])
        parts[name] = _build(cls, values, name)
    try:
        parts["turntable"] = turntable_options_from_dict(data.get("turntable", {}))
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"[turntable] {exc}") from exc
    lidar_values = dict(data.get("lidar", {}))
    try:
        base = lidar_preset(lidar_values.pop("preset", "urg-04lx-ug01"))
    except ValueError as exc:
        raise ConfigError(f"[lidar] {exc}") from exc
    unknown = sorted(set(lidar_values) - set(_known(LidarSpec)))
    if unknown:
        raise ConfigError(f"unknown key(s) {', '.join(unknown)} in [lidar]; valid keys: preset, "
                          f"{', '.join(_known(LidarSpec))}")
    try:
        lidar = base.replace(**lidar_values) if lidar_values else base
        return RunConfig(lidar=lidar, **parts, **{k: data[k] for k in _TOP_LEVEL if k in data},
                         explicit=frozenset(given_keys(data)))
    except (TypeError, ValueError) as exc:
        raise ConfigError(str(exc)) from exc


def recorded_settings(recorded: dict[str, Any]) -> dict[str, Any]:
    """The settings of a recorded scan, ready for :func:`config_from_dict`.

    ``recorded`` is a sidecar's ``config`` (:meth:`RunConfig.to_dict`: every setting,
    resolved, in the dataclasses' nesting). Returned in the TOML layout, with only the
    settings that differ from the defaults, so a scan is run again exactly (same seed,
    same parts) and options given on top of them are refused or honoured as if given
    with the original ones. ``config_from_dict(recorded_settings(c)).to_dict()`` is ``c``
    (as JSON: lists for tuples).

    Raises:
        ConfigError: when ``recorded`` is not a recorded configuration.
    """
    def layout(config: dict[str, Any]) -> dict[str, Any]:
        try:
            out = {name: dict(config[name]) for name in list(_SECTIONS) + ["lidar"]}
            out.update({name: config[name] for name in _TOP_LEVEL})
            recorded_table = config["turntable"]
            dynamics = dict(recorded_table["dynamics"])
            turntable = {key: value for key, value in recorded_table.items() if key not in ("dynamics", "encoder")}
            turntable.update(servo=dict(dynamics.pop("servo")), jitter=dict(dynamics.pop("jitter")), **dynamics)
            encoder = dict(recorded_table["encoder"])
            if encoder.get("ticks_per_rev") is None:
                encoder["ticks_per_rev"] = 0  # the TOML's "exact"
            turntable["encoder"] = encoder
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise ConfigError(f"not a recorded scan configuration (a sidecar's \"config\"): {type(exc).__name__}: "
                              f"{exc}") from exc
        out["turntable"] = turntable
        return out

    def differing(values: dict[str, Any], defaults: dict[str, Any]) -> dict[str, Any]:
        out = {}
        for key, value in values.items():
            default = defaults.get(key)
            if isinstance(value, dict) and isinstance(default, dict):
                value = differing(value, default)
                if value:
                    out[key] = value
            elif key not in defaults or value != default:
                out[key] = value
        return out

    if not isinstance(recorded, dict):
        raise ConfigError(f"a recorded configuration is a JSON object, got {type(recorded).__name__}")
    import json

    def as_json(value: Any) -> Any:
        return json.loads(json.dumps(value))  # as a sidecar holds it: lists, not tuples

    defaults = as_json(RunConfig().to_dict())
    settings = layout(recorded)
    out = differing(settings, layout(defaults))
    # Another preset's LiDAR is that preset and what differs from it: its own noise, resolution
    # and the rest are then no settings the user gave, which the plan would refuse when their
    # effect is off (a UTM-30LX scanned with [sensor_model] range_noise = false).
    name = settings["lidar"].get("name")
    if name in PRESETS and name != defaults["lidar"]["name"]:
        lidar = differing(settings["lidar"], as_json(dataclasses.asdict(PRESETS[name])))
        out["lidar"] = {"preset": name, **lidar}
    return out


def load_settings(path: str | os.PathLike) -> tuple[dict[str, Any], Path | None]:
    """The settings of a ``--config`` file, and the folder its relative mesh path is in.

    A TOML file (mesh paths relative to its folder), or a scan's sidecar, told by its
    content (a JSON object; a TOML document cannot open with ``{``): its recorded
    configuration (:func:`recorded_settings`) runs that scan again, and its mesh path
    is as recorded (folder None).

    Raises:
        FileNotFoundError: no such file.
        ConfigError: not valid TOML, or a JSON object that is not a sidecar.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"config file not found: {path}")
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path} cannot be read as text: {exc}") from exc
    if not text.lstrip().startswith("{"):
        return load_toml(path), path.resolve().parent
    import json

    try:
        meta = json.loads(text)
    except ValueError as exc:
        raise ConfigError(f"{path} is not a readable JSON file: {exc}") from exc
    if not isinstance(meta, dict) or "config" not in meta:
        raise ConfigError(f"{path} is not a plantsim sidecar (no \"config\" key); give a TOML file or the "
                          ".json written beside a scan's cloud")
    return recorded_settings(meta["config"]), None


def load_toml(path: str | os.PathLike) -> dict[str, Any]:
    """Reads a TOML configuration file."""
    if sys.version_info >= (3, 11):  # imported here: a scan without a file never parses TOML
        import tomllib
    else:  # pragma: no cover - exercised on 3.10 only
        import tomli as tomllib

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"config file not found: {path}")
    try:
        with path.open("rb") as handle:
            return tomllib.load(handle)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path} is not valid TOML: {exc}") from exc


def merge(base: dict, overrides: dict) -> dict:
    """Nested dict merge: ``overrides`` wins; sections are merged key by key."""
    out = {k: (dict(v) if isinstance(v, dict) else v) for k, v in base.items()}
    for key, value in overrides.items():
        if isinstance(value, dict):
            out[key] = {**out.get(key, {}), **value}
        else:
            out[key] = value
    return out
