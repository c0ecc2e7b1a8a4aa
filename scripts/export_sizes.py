"""Prints the size of one simulated scan's cloud in every export format, and LAZ/LAS.

    python scripts/export_sizes.py [step_deg]
"""

import sys
import time

import numpy as np
import trimesh

from plantsim.cloud import export as pio
from plantsim.cloud.reconstruct import reconstruct
from plantsim.plant.mesh import plant_from_arrays
from plantsim.rig.geometry import RigGeometry
from plantsim.rig.scene import build_scene
from plantsim.scan.pipeline import step_and_shoot
from plantsim.scan.schedule import StepScan
from plantsim.sensor.spec import URG_04LX_UG01


def main(step_deg: float = 2.0) -> None:
    box = trimesh.creation.box(extents=[0.04, 0.06, 0.12])
    plant = plant_from_arrays(np.asarray(box.vertices), np.asarray(box.faces))
    raw = step_and_shoot(build_scene(RigGeometry(), plant), URG_04LX_UG01, StepScan(step_deg=step_deg))
    cloud = reconstruct(raw, intensity=np.linspace(0, 1, raw.range_m.size).reshape(raw.range_m.shape))
    print(f"{len(cloud)} points (box plant, {step_deg} deg steps)")
    sizes = {}
    for suffix in pio.EXPORTERS:
        runs = []
        for _ in range(3):
            start = time.perf_counter()
            data = pio.encode_cloud("c" + suffix, cloud)
            runs.append(time.perf_counter() - start)
        sizes[suffix] = len(data)
        print(f"{suffix:5s} {len(data) / 1e6:8.3f} MB  {len(data) / len(cloud):6.1f} B/point  "
              f"encode {1e3 * float(np.median(runs)):7.1f} ms (median of 3)")
    print(f"LAZ/LAS size ratio: {sizes['.laz'] / sizes['.las']:.3f}")


if __name__ == "__main__":
    main(*(float(a) for a in sys.argv[1:]))
