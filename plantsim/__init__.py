"""plantsim: a MuJoCo simulator of a 2D-LiDAR + turntable plant-phenotyping scanner.

The public surface, in one place::

    import plantsim
    plant = plantsim.load_plant("plant.stl", units="mm", up="y")
    scene = plantsim.build_scene(plantsim.RigGeometry(), plant)
    raw = plantsim.step_and_shoot(scene, plantsim.URG_04LX_UG01, plantsim.StepScan(step_deg=1))
    cloud = plantsim.reconstruct(raw)
    plantsim.write_cloud("scan.las", cloud)
"""

from plantsim.scan.config import OutputOptions, PlantOptions, RunConfig, config_from_dict, load_toml
from plantsim.errors import (
    ConfigError,
    HardwareError,
    JournalError,
    MeshError,
    PlantSimError,
    SceneError,
    ServoAlarmError,
    ServoCommunicationError,
    ScanInterruptedError,
    SimulationError,
)
from plantsim.cloud.export import CLASSIFICATION, EXPORTERS, read_cloud, write_cloud
from plantsim.plant.mesh import PlantMesh, load_plant, plant_from_arrays
from plantsim.scan.pipeline import ScanResult, run_scan, simulated_rig_time_s, with_evaluation, write_result
from plantsim.plant.procedural import PART_EAR, PART_LEAF, PART_STEM, MaizeParams, ProceduralPlant, WheatParams, make_maize, make_wheat
from plantsim.cloud.reconstruct import PointCloud, reconstruct
from plantsim.resources import bundled_plant_path
from plantsim.rig.geometry import RigGeometry
from plantsim.scan.rig import RigScanResult, run_rig_scan, write_rig_result
from plantsim.scan.raw import RawScan
from plantsim.sensor.casting import RayCaster
from plantsim.scan.schedule import StepScan
from plantsim.scan.pipeline import step_and_shoot
from plantsim.rig.scene import HitClass, Scene, build_scene
from plantsim.scan.session import LineSource, SimulatedLidar, UrgLidar, run_session
from plantsim.turntable.servo import PositionController, ServoConfig, ShaftSim, plan_profile
from plantsim.sensor.spec import PRESETS, URG_04LX_UG01, BeamStatus, LidarSpec, lidar_preset
from plantsim.transforms import apply_T, invert_T, make_T
from plantsim.turntable.table import SimulatedTurntable, Turntable

__version__ = "0.1.0"

# Names whose modules import scipy's heavier parts (or matplotlib): loaded on first
# use, so that ``plantsim scan`` without ``--evaluate`` does not pay for them.
_LAZY = {
    "ServoTurntable": "plantsim.hardware.dynamixel.turntable",
    "Evaluation": "plantsim.evaluation.evaluate",
    "EvaluationOptions": "plantsim.evaluation.evaluate",
    "evaluate_scan": "plantsim.evaluation.evaluate",
    "cloud_mesh_metrics": "plantsim.evaluation.metrics",
    "extract_traits": "plantsim.evaluation.traits",
    "traits_from_mesh": "plantsim.evaluation.traits",
    "Sweep": "plantsim.evaluation.study",
    "run_study": "plantsim.evaluation.study",
    "pareto_front": "plantsim.evaluation.study",
}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'plantsim' has no attribute {name!r}")
