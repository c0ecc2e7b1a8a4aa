"""The reference a user would write without plantsim, for scripts/bench_scan.py to time.

MuJoCo loads the STL itself, a hinge carries it, the URG-04LX's 683-beam fan from
0.35 m, the points turned back into the table frame and saved with numpy. No
placement, no classes, no misses kept, no sidecar. Two flavours:

- ``typical``: the mesh geom as MJCF makes it by default (MuJoCo builds its convex
  hull), one ``mj_multiRay`` call per scan line (MuJoCo's API for one fan of rays);
- ``lean``: what a MuJoCo expert writes: no collision hull (contype 0), a shell
  inertia, every line in one ``mujoco.batch`` call on two threads.

    python scripts/bare_mujoco_scan.py MESH.stl UP STEP_DEG OUT.npy [typical|lean]
"""

import sys

import mujoco
import mujoco.batch
import numpy as np

mesh, up, step, out = sys.argv[1], sys.argv[2], float(sys.argv[3]), sys.argv[4]
flavour = sys.argv[5] if len(sys.argv) > 5 else "typical"
quat = {"x": "0.7071068 0 -0.7071068 0", "y": "0.7071068 0.7071068 0 0", "z": "1 0 0 0"}[up]
lean = flavour == "lean"
mesh_attrs = ' inertia="shell"' if lean else ""
geom_attrs = ' contype="0" conaffinity="0" mass="0.1"' if lean else ""
xml = f"""<mujoco><compiler angle="radian"/><asset><mesh name="plant" file="{mesh}"{mesh_attrs}/></asset>
<worldbody><body name="table"><joint name="hinge" axis="0 0 1"/>
<geom type="mesh" mesh="plant" quat="{quat}"{geom_attrs}/></body>
</worldbody></mujoco>"""
model = mujoco.MjModel.from_xml_string(xml)
angles = np.deg2rad(np.arange(0, 360, step))
a = np.deg2rad(-119.53125 + 0.3515625 * np.arange(683))
dirs = np.stack([-np.cos(a), np.zeros_like(a), np.sin(a)], axis=1)
origin = np.array([0.35, 1e-9, 0.15])
if lean:
    batch = mujoco.batch.Batch(model, nsim=len(angles), nthread=2)
    batch.bind("qpos")[:, 0] = angles
    dist, geom = batch.ray(origin, dirs)
else:
    data = mujoco.MjData(model)
    dist = np.empty((len(angles), len(a)))
    geom = np.empty((len(angles), len(a)), dtype=np.int32)
    flat = dirs.ravel()
    for k, angle in enumerate(angles):
        data.qpos[0] = angle
        mujoco.mj_kinematics(model, data)
        mujoco.mj_multiRay(model, data, origin, flat, None, 1, -1, geom[k], dist[k], None, len(a), 10.0)
line, beam = np.nonzero(dist >= 0)
p = origin + dist[line, beam, None] * dirs[beam]
c, s = np.cos(-angles[line]), np.sin(-angles[line])
np.save(out, np.stack([c * p[:, 0] - s * p[:, 1], s * p[:, 0] + c * p[:, 1], p[:, 2]], axis=1))
