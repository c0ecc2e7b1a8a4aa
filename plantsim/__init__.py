"""plantsim: a MuJoCo simulator of a 2D-LiDAR + turntable plant-phenotyping scanner.

One scan pipeline serves every mode: a schedule x a turntable motion (kinematic,
MuJoCo physics, or a real servo) x a line source (the simulated LiDAR, ideal or
realistic) -> one raw record (a ROS 2 bag) -> reconstruction from what a real rig
knows -> cloud. The public surface, in one place::

    import plantsim

    config = plantsim.RunConfig(
        scan=plantsim.StepScan(step_deg=1),
        turntable=plantsim.TurntableOptions(
            physics="dynamic", jitter=...),              # or mode="continuous", rpm=2
        output=plantsim.OutputOptions(path="scan.las", raw="scan_raw"))
    result = plantsim.run_scan(config)                   # sensor="realistic" by default
    plantsim.write_result(result)                        # cloud, sidecar, ROS 2 bag

    raw, info = plantsim.read_raw("scan_raw")            # any bag with the same conventions
    cloud = plantsim.reconstruct(raw)

Names whose modules pull in heavier dependencies (scipy's spatial code,
matplotlib, rosbags, the hardware drivers) load on first use.
"""

from plantsim.cloud.export import CLASSIFICATION, EXPORTERS, read_cloud, write_cloud
from plantsim.cloud.reconstruct import PointCloud, reconstruct
from plantsim.errors import (
    ConfigError,
    HardwareError,
    JournalError,
    MeshError,
    PlantSimError,
    ScanInterruptedError,
    SceneError,
    ServoAlarmError,
    ServoCommunicationError,
    SimulationError,
    Terminated,
    UnsafeStopError,
)
from plantsim.plant.mesh import PlantMesh, load_plant, plant_from_arrays
from plantsim.plant.procedural import (
    PART_EAR,
    PART_LEAF,
    PART_STEM,
    MaizeParams,
    ProceduralPlant,
    WheatParams,
    make_maize,
    make_wheat,
)
from plantsim.resources import bundled_plant_path
from plantsim.rig.geometry import RigGeometry
from plantsim.rig.scene import HitClass, Scene, build_scene
from plantsim.scan.config import OutputOptions, PlantOptions, RunConfig, config_from_dict, load_toml
from plantsim.scan.pipeline import ScanResult, run_scan, simulated_rig_time_s, with_evaluation, write_result
from plantsim.scan.plan import ScanPlan, plan_scan
from plantsim.scan.raw import ANGLE_MODES, BeamGrid, RawScan
from plantsim.scan.schedule import StepScan
from plantsim.sensor.casting import Caster, MujocoBackend
from plantsim.sensor.lidar import SimulatedLidar
from plantsim.sensor.model import SensorModel
from plantsim.sensor.spec import PRESETS, URG_04LX_UG01, BeamStatus, LidarSpec, lidar_preset
from plantsim.transforms import apply_T, invert_T, make_T
from plantsim.turntable.dynamics import JitterConfig, TurntableDynamics
from plantsim.turntable.encoder import EncoderConfig
from plantsim.turntable.options import TurntableOptions
from plantsim.turntable.servo import ServoConfig
from plantsim.turntable.table import SimulatedTurntable, Turntable

__version__ = "0.2.0"

# Loaded on first use, so that a plain scan does not pay for them.
_LAZY = {
    "ServoTurntable": "plantsim.hardware.dynamixel.turntable",
    "read_raw": "plantsim.cloud.bag",
    "write_raw": "plantsim.cloud.bag",
    "Evaluation": "plantsim.evaluation.evaluate",
    "EvaluationOptions": "plantsim.evaluation.evaluate",
    "evaluate_scan": "plantsim.evaluation.evaluate",
    "cloud_mesh_metrics": "plantsim.evaluation.metrics",
    "extract_traits": "plantsim.evaluation.traits",
    "traits_from_mesh": "plantsim.evaluation.traits",
    "Sweep": "plantsim.evaluation.study",
    "run_study": "plantsim.evaluation.study",
    "pareto_front": "plantsim.evaluation.study",
    "calibrate": "plantsim.cloud.calibration",
    "Calibration": "plantsim.cloud.calibration",
    "CalibrationTarget": "plantsim.plant.target",
    "CALIBRATION_TARGET": "plantsim.plant.target",
    "fit_sensor": "plantsim.sensor.fit",
    "FlatTargetRecording": "plantsim.sensor.fit",
    "SensorFit": "plantsim.sensor.fit",
    "FlatTarget": "plantsim.sensor.flat_target",
    "simulate_flat_target": "plantsim.sensor.flat_target",
    "SafeStop": "plantsim.hardware.safety",
    "StopAction": "plantsim.hardware.safety",
    "SafeStopReport": "plantsim.hardware.safety",
    "ServoStatus": "plantsim.hardware.dynamixel.turntable",
    "render_scene": "plantsim.cloud.render",
    "render_cloud": "plantsim.cloud.render",
    "error_picture": "plantsim.cloud.render",
    "View": "plantsim.cloud.render",
    "RenderError": "plantsim.cloud.render",
    "dask_executor": "plantsim.evaluation.study",
    "SettingTypeError": "plantsim.validation",
    "MissingExtraError": "plantsim.validation",
    "UrgLidar": "plantsim.hardware.urg",
    "UrgEmulator": "plantsim.hardware.urg",
}

__all__ = [
    # scanning
    "RunConfig", "PlantOptions", "OutputOptions", "StepScan", "TurntableOptions", "TurntableDynamics",
    "JitterConfig", "EncoderConfig", "ServoConfig", "SensorModel", "LidarSpec", "PRESETS", "URG_04LX_UG01",
    "lidar_preset", "RigGeometry", "config_from_dict", "load_toml", "plan_scan", "ScanPlan", "run_scan",
    "ScanResult", "write_result", "with_evaluation", "simulated_rig_time_s",
    # parts
    "load_plant", "plant_from_arrays", "PlantMesh", "bundled_plant_path", "build_scene", "Scene", "HitClass",
    "SimulatedLidar", "Caster", "MujocoBackend", "BeamStatus", "Turntable", "SimulatedTurntable",
    "ServoTurntable", "ServoStatus", "SafeStop", "StopAction", "SafeStopReport",
    # the raw record and the cloud
    "RawScan", "BeamGrid", "ANGLE_MODES", "read_raw", "write_raw", "reconstruct", "PointCloud", "read_cloud",
    "write_cloud", "EXPORTERS", "CLASSIFICATION",
    # pictures
    "render_scene", "render_cloud", "error_picture", "View", "RenderError",
    # the real LiDAR
    "UrgLidar", "UrgEmulator",
    # calibration and the sensor fit
    "calibrate", "Calibration", "CalibrationTarget", "CALIBRATION_TARGET", "fit_sensor", "FlatTargetRecording",
    "SensorFit", "FlatTarget", "simulate_flat_target",
    # procedural plants
    "make_maize", "make_wheat", "MaizeParams", "WheatParams", "ProceduralPlant", "PART_STEM", "PART_LEAF",
    "PART_EAR",
    # evaluation
    "Evaluation", "EvaluationOptions", "evaluate_scan", "cloud_mesh_metrics", "extract_traits",
    "traits_from_mesh", "Sweep", "run_study", "pareto_front", "dask_executor", "SettingTypeError",
    "MissingExtraError",
    # transforms
    "make_T", "invert_T", "apply_T",
    # errors
    "PlantSimError", "ConfigError", "MeshError", "SceneError", "SimulationError", "HardwareError",
    "ServoAlarmError", "ServoCommunicationError", "ScanInterruptedError", "JournalError", "UnsafeStopError",
    "Terminated",
]


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'plantsim' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(__all__))
