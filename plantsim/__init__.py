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
    smooth = plantsim.reconstruct(plantsim.filter_ranges(raw)[0])   # ranges denoised first

Every name loads its module on first use: ``import plantsim`` costs nothing, and
a scan pays only for the parts it runs.
"""

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

__version__ = "0.2.0"

# Every name loads its module on first use, so that ``import plantsim`` and the command line
# pay only for what a run uses: a scan loads neither the procedural plants nor the evaluation,
# the hardware drivers, rosbags or matplotlib, and a command that never draws can keep MuJoCo
# from probing for OpenGL (plantsim.cli.app). The module of each name:
_LAZY_MODULES = {
    "plantsim.cloud.export": "CLASSIFICATION EXPORTERS read_cloud write_cloud",
    "plantsim.cloud.reconstruct": "PointCloud reconstruct",
    "plantsim.cloud.denoise": "filter_ranges",
    "plantsim.plant.mesh": "PlantMesh load_plant plant_from_arrays",
    "plantsim.plant.procedural": ("PART_EAR PART_LEAF PART_STEM MaizeParams ProceduralPlant WheatParams make_maize "
                                  "make_wheat RosetteParams make_rosette DicotParams make_dicot PART_PETIOLE PART_BRANCH PART_NAMES "
                                  "to_labelled_obj_bytes"),
    "plantsim.plant.labels": ("LabelledPart read_labelled_parts parts_from_face_labels parts_from_colours "
                              "PART_COLOURS_RGB"),
    "plantsim.resources": "bundled_plant_path",
    "plantsim.rig.geometry": "RigGeometry",
    "plantsim.rig.scene": "HitClass Scene build_scene",
    "plantsim.scan.config": "OutputOptions PlantOptions RangeFilter RunConfig config_from_dict load_toml load_settings recorded_settings",
    "plantsim.scan.pipeline": "ScanResult run_scan simulated_rig_time_s with_evaluation write_result performance",
    "plantsim.scan.plan": "ScanPlan plan_scan",
    "plantsim.scan.raw": "ANGLE_MODES BeamGrid RawScan",
    "plantsim.scan.schedule": "StepScan",
    "plantsim.sensor.casting": "Caster MujocoBackend",
    "plantsim.sensor.lidar": "SimulatedLidar",
    "plantsim.sensor.model": "SensorModel",
    "plantsim.sensor.spec": "PRESETS URG_04LX_UG01 BeamStatus LidarSpec lidar_preset",
    "plantsim.transforms": "apply_T invert_T make_T",
    "plantsim.turntable.dynamics": "JitterConfig TurntableDynamics DynamicsDiagnostics",
    "plantsim.turntable.encoder": "EncoderConfig",
    "plantsim.turntable.options": "TurntableOptions",
    "plantsim.turntable.servo": "ServoConfig",
    "plantsim.turntable.table": "SimulatedTurntable Turntable",
    "plantsim.hardware.dynamixel.turntable": "ServoTurntable ServoStatus",
    "plantsim.cloud.bag": "read_raw write_raw",
    "plantsim.evaluation.evaluate": "Evaluation EvaluationOptions evaluate_scan evaluation_threads scan_beam_gaps scan_range_noise truth_from_labelled_mesh truth_notes",
    "plantsim.evaluation.metrics": "cloud_mesh_metrics",
    "plantsim.evaluation.traits": "extract_traits traits_from_mesh",
    "plantsim.evaluation.study": "Sweep run_study pareto_front dask_executor",
    "plantsim.cloud.calibration": "calibrate Calibration",
    "plantsim.plant.target": "CalibrationTarget CALIBRATION_TARGET",
    "plantsim.sensor.fit": "fit_sensor FlatTargetRecording SensorFit",
    "plantsim.sensor.flat_target": "FlatTarget simulate_flat_target",
    "plantsim.hardware.safety": "SafeStop StopAction SafeStopReport",
    "plantsim.interrupts": "raise_if_signalled",
    "plantsim.cloud.render": "render_scene render_cloud error_picture error_picture_of ErrorPicture View RenderError",
    "plantsim.validation": "SettingTypeError MissingExtraError",
    "plantsim.evaluation.angle_error": "angle_error_displacement",
    "plantsim.hardware.urg": "UrgLidar UrgEmulator",
    "plantsim.hardware.urg.source": "UrgLineSource",
    "plantsim.hardware.urg.pair": "EmulatorPair",
}
_LAZY = {name: module for module, names in _LAZY_MODULES.items() for name in names.split()}

__all__ = [
    # scanning
    "RunConfig", "PlantOptions", "OutputOptions", "StepScan", "TurntableOptions", "TurntableDynamics",
    "JitterConfig", "EncoderConfig", "ServoConfig", "SensorModel", "LidarSpec", "PRESETS", "URG_04LX_UG01",
    "lidar_preset", "RigGeometry", "config_from_dict", "load_toml", "load_settings", "recorded_settings",
    "plan_scan", "ScanPlan", "run_scan",
    "ScanResult", "write_result", "with_evaluation", "simulated_rig_time_s", "performance",
    # parts
    "load_plant", "plant_from_arrays", "PlantMesh", "bundled_plant_path", "build_scene", "Scene", "HitClass",
    "SimulatedLidar", "Caster", "MujocoBackend", "BeamStatus", "Turntable", "SimulatedTurntable",
    "ServoTurntable", "ServoStatus", "SafeStop", "StopAction", "SafeStopReport", "raise_if_signalled",
    # the raw record and the cloud
    "RawScan", "BeamGrid", "ANGLE_MODES", "read_raw", "write_raw", "reconstruct", "RangeFilter", "filter_ranges",
    "PointCloud", "read_cloud",
    "write_cloud", "EXPORTERS", "CLASSIFICATION",
    # what the turntable did
    "DynamicsDiagnostics", "angle_error_displacement",
    # pictures
    "render_scene", "render_cloud", "error_picture", "error_picture_of", "ErrorPicture", "View", "RenderError",
    # the real LiDAR
    "UrgLidar", "UrgEmulator", "UrgLineSource", "EmulatorPair",
    # calibration and the sensor fit
    "calibrate", "Calibration", "CalibrationTarget", "CALIBRATION_TARGET", "fit_sensor", "FlatTargetRecording",
    "SensorFit", "FlatTarget", "simulate_flat_target",
    # procedural plants
    "make_maize", "make_wheat", "make_rosette", "MaizeParams", "WheatParams", "RosetteParams", "ProceduralPlant", "PART_STEM", "PART_LEAF",
    "PART_EAR", "make_dicot", "DicotParams", "PART_PETIOLE", "PART_BRANCH", "PART_NAMES", "to_labelled_obj_bytes",
    "LabelledPart", "read_labelled_parts", "parts_from_face_labels", "parts_from_colours", "PART_COLOURS_RGB",
    # evaluation
    "Evaluation", "EvaluationOptions", "evaluate_scan", "evaluation_threads", "scan_beam_gaps", "scan_range_noise", "truth_from_labelled_mesh", "truth_notes", "cloud_mesh_metrics", "extract_traits",
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

        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value  # the next look-up is a plain attribute
        return value
    raise AttributeError(f"module 'plantsim' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(__all__))
