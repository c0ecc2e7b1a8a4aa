"""The same turntable scan written with MuJoCo-LiDAR's CPU backend, as its README shows it.

    pip install 'plantsim[bench]'      # mujoco-lidar
    python scripts/mujoco_lidar_scan.py MESH.stl UP STEP_DEG OUT.npy

A peer for scripts/bench_peers.py to time. The scene is what a MuJoCo-LiDAR user
writes: MuJoCo loads the STL, a hinge carries it, a site marks the LiDAR (its x
axis towards the turntable axis, its y axis up, so the fan's azimuth ``theta``
sweeps the vertical scan plane); ``MjLidarWrapper(model, site_name, backend="cpu")``
casts the URG-04LX's 683-beam fan (``mj_multiRay`` underneath) once per line after
``mj_forward``; ``get_hit_points()`` gives the points in the site frame, which are
turned into the turntable frame and saved with numpy. The site sits 1e-9 m off the
scan plane, as in scripts/bare_mujoco_scan.py: MuJoCo's mesh BVH can cull rays that
lie exactly in a plane of mesh vertices (../shared/notes/mujoco-raycasting.md).
"""

import sys

import mujoco
import numpy as np
from mujoco_lidar import MjLidarWrapper

mesh, up, step, out = sys.argv[1], sys.argv[2], float(sys.argv[3]), sys.argv[4]
quat = {"x": "0.7071068 0 -0.7071068 0", "y": "0.7071068 0.7071068 0 0", "z": "1 0 0 0"}[up]
xml = f"""<mujoco><compiler angle="radian"/><asset><mesh name="plant" file="{mesh}"/></asset>
<worldbody><body name="table"><joint name="hinge" axis="0 0 1"/>
<geom type="mesh" mesh="plant" quat="{quat}"/></body>
<site name="lidar" pos="0.35 1e-9 0.15" xyaxes="-1 0 0 0 0 1"/>
</worldbody></mujoco>"""
model = mujoco.MjModel.from_xml_string(xml)
data = mujoco.MjData(model)
lidar = MjLidarWrapper(model, site_name="lidar", backend="cpu", cutoff_dist=5.6)
theta = np.deg2rad(-119.53125 + 0.3515625 * np.arange(683))  # the URG-04LX's 683 beams
phi = np.zeros_like(theta)
angles = np.deg2rad(np.arange(0, 360, step))
clouds = []
for angle in angles:
    data.qpos[0] = angle
    mujoco.mj_forward(model, data)
    distances = lidar.trace_rays(data, theta, phi)
    hit = distances > 0
    site = data.site("lidar")
    points_world = site.xpos + lidar.get_hit_points()[hit] @ site.xmat.reshape(3, 3).T
    c, s = np.cos(-angle), np.sin(-angle)
    x, y = points_world[:, 0], points_world[:, 1]
    clouds.append(np.stack([c * x - s * y, s * x + c * y, points_world[:, 2]], axis=1))
np.save(out, np.concatenate(clouds))
