"""Pictures of the rig, the plant, the LiDAR's fan and a cloud, with MuJoCo's renderer.

The scene is the scan's own (:func:`plantsim.rig.scene.build_spec`), compiled
with an offscreen buffer of the picture's size and drawn through an OpenGL
context without a display: EGL, else OSMesa (``MUJOCO_GL=egl`` or ``osmesa``
chooses one). Points and the fan's beams are drawn as extra visual geoms added
to the scene after MuJoCo fills it, so they never touch the model the LiDAR
casts against.

Colours: by class (plant green, turntable blue, rig grey) or by the distance of
each point to the true mesh (blue 0 -> red at ``error_max_m``).
"""

from __future__ import annotations

import dataclasses
import io
import logging
import os
import sys
import zlib
from typing import Any

import mujoco
import numpy as np

from plantsim.errors import PlantSimError
from plantsim.plant.mesh import PlantMesh
from plantsim.rig.geometry import RigGeometry
from plantsim.rig.scene import HitClass, build_spec

logger = logging.getLogger(__name__)

# RGBA per class.
CLASS_RGBA = {HitClass.PLANT: (0.15, 0.75, 0.2, 1.0), HitClass.TURNTABLE: (0.2, 0.45, 0.95, 1.0),
              HitClass.RIG: (0.55, 0.55, 0.55, 1.0), HitClass.NONE: (1.0, 0.0, 1.0, 1.0)}
FAN_RGBA = (1.0, 0.15, 0.1, 0.6)


class RenderError(PlantSimError):
    """No offscreen OpenGL context could be made (the message says what to install)."""


@dataclasses.dataclass(frozen=True, kw_only=True)
class View:
    """Where the free camera looks from.

    Attributes:
      width, height: pixels.
      azimuth_deg: camera azimuth about the world z axis, degrees.
      elevation_deg: camera elevation, degrees (negative looks down).
      distance_m: camera distance from ``lookat``, metres (None: fit the scene).
      lookat: (3,) world point the camera looks at, metres (None: the plant's centre).
    """

    width: int = 960
    height: int = 720
    azimuth_deg: float = 210.0
    elevation_deg: float = -25.0
    distance_m: float | None = None
    lookat: tuple[float, float, float] | None = None

    def __post_init__(self) -> None:
        from plantsim.validation import check_int, check_number

        check_int("View", "width", self.width, minimum=16, maximum=8192)
        check_int("View", "height", self.height, minimum=16, maximum=8192)
        check_number("View", "azimuth_deg", self.azimuth_deg)
        check_number("View", "elevation_deg", self.elevation_deg, minimum=-90, maximum=90)
        if self.distance_m is not None:
            check_number("View", "distance_m", self.distance_m, minimum=0, strict_minimum=True)


def _gl_context(width: int, height: int):
    """An offscreen OpenGL context: MUJOCO_GL's choice, else EGL then OSMesa."""
    wanted = os.environ.get("MUJOCO_GL", "").lower()
    order = [wanted] if wanted in ("egl", "osmesa", "glfw") else ["egl", "osmesa"]
    errors = []
    for name in order:
        platform = os.environ.get("PYOPENGL_PLATFORM")
        if "OpenGL" in sys.modules and platform and platform != name and name != "glfw":
            errors.append(f"{name}: PyOpenGL already loaded for {platform}")
            continue
        try:
            if name == "egl":
                from mujoco.egl import GLContext
            elif name == "osmesa":
                os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")
                from mujoco.osmesa import GLContext
            else:
                from mujoco.glfw import GLContext
            context = GLContext(width, height)
            context.make_current()
            logger.debug("rendering with %s", name)
            return context
        except Exception as exc:  # each backend fails in its own way (ImportError, RuntimeError, ...)
            errors.append(f"{name}: {type(exc).__name__}: {exc}")
    raise RenderError(
        "no offscreen OpenGL: " + "; ".join(errors) + ". Install EGL (apt-get install libegl1) "
        "or OSMesa (apt-get install libosmesa6) and set MUJOCO_GL=egl or MUJOCO_GL=osmesa")


def _class_colours(hit_class: np.ndarray) -> np.ndarray:
    table = np.array([CLASS_RGBA[HitClass(c)] if c in iter(HitClass) else CLASS_RGBA[HitClass.NONE]
                      for c in range(4)], dtype=np.float32)
    return table[np.clip(hit_class.astype(np.int64), 0, 3)]


def error_colours(distance_m: np.ndarray, error_max_m: float) -> np.ndarray:
    """(n, 4) RGBA: blue at 0, through green and yellow, to red at ``error_max_m`` and beyond."""
    t = np.clip(np.asarray(distance_m, np.float64) / error_max_m, 0.0, 1.0)
    stops = np.array([[0.1, 0.2, 0.9], [0.1, 0.8, 0.3], [0.95, 0.85, 0.1], [0.9, 0.1, 0.1]])
    x = t * (len(stops) - 1)
    i = np.minimum(x.astype(int), len(stops) - 2)
    f = (x - i)[:, None]
    rgb = stops[i] * (1 - f) + stops[i + 1] * f
    return np.column_stack([rgb, np.ones(len(t))]).astype(np.float32)


def _fan(model: mujoco.MjModel, data: mujoco.MjData, rig: RigGeometry, plant, lidar,
         n_rays: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Beam segments (start, end) in the world frame, each ending where it hits.

    Directions are the simulated LiDAR's own (its caster), so the fan drawn is
    the fan cast.
    """
    from plantsim.rig.scene import LIDAR_GEOMGROUP, build_scene
    from plantsim.scan.raw import BeamGrid
    from plantsim.sensor.lidar import SimulatedLidar

    angles = BeamGrid.of(lidar).beam_angles_rad()
    caster = SimulatedLidar(build_scene(rig, plant), lidar, angles).caster
    dirs = np.asarray(caster.dirs_base, dtype=np.float64).reshape(len(angles), -1, 3).mean(axis=1)
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    origin = np.asarray(caster.origins_base, dtype=np.float64).reshape(-1, 3)[0]
    pick = np.unique(np.linspace(0, len(angles) - 1, n_rays).round().astype(int))
    lidar_body = model.body("lidar").id
    segments = []
    geomid = np.array([-1], dtype=np.int32)
    for direction in dirs[pick]:
        dist = mujoco.mj_ray(model, data, origin, direction, LIDAR_GEOMGROUP, 1, lidar_body, geomid)
        length = dist if dist >= 0 else min(lidar.range_max_m, 1.0)
        segments.append((origin, origin + direction * length))
    return segments


def two_sided(plant: PlantMesh) -> PlantMesh:
    """The plant with every face also wound the other way, on its own vertices (drawing only).

    A leaf is one sheet of triangles, and OpenGL culls the side facing away from its
    winding, so a leaf seen from behind vanished from the picture while its shadow stayed.
    The reversed copy gets its own vertices so that MuJoCo's per-vertex normals (averaged
    over the faces that share a vertex) point out of each side instead of cancelling.
    """
    n = len(plant.vertices_mesh)
    return dataclasses.replace(plant, vertices_mesh=np.vstack([plant.vertices_mesh, plant.vertices_mesh]),
                               faces=np.vstack([plant.faces, plant.faces[:, ::-1] + n]).astype(plant.faces.dtype))


def render_scene(rig: RigGeometry, plant=None, *, points_turntable: np.ndarray | None = None,
                 point_rgba: np.ndarray | None = None, lidar=None, fan_rays: int = 41,
                 view: View = View(), point_radius_m: float = 0.0015,
                 max_points: int = 20_000, turntable_angle_rad: float = 0.0,
                 overlay: str | None = None) -> np.ndarray:
    """Draws the rig, the plant, the fan and points; returns an (h, w, 3) uint8 image.

    Args:
      rig: rig geometry.
      plant: the placed plant (PlantMesh) or None.
      points_turntable: (n, 3) float64, metres, turntable frame, or None.
      point_rgba: (n, 4) float colours of the points (None: magenta).
      lidar: LidarSpec whose fan is drawn (None: no fan).
      fan_rays: beams of the fan drawn (evenly spread over the field of view).
      view: the camera.
      point_radius_m: half the side of the cubes drawn for points.
      max_points: at most this many points are drawn (an even subsample).
      turntable_angle_rad: the turntable's angle (points turn with it).
      overlay: text drawn in the top-left corner (lines split by "\n"), or None.

    Raises:
      RenderError: no offscreen OpenGL context (names what to install).
    """
    spec = build_spec(rig, None if plant is None else two_sided(plant))
    spec.visual.global_.offwidth = view.width
    spec.visual.global_.offheight = view.height
    spec.visual.quality.shadowsize = 2048
    model = spec.compile()
    data = mujoco.MjData(model)
    data.qpos[model.jnt_qposadr[model.joint("turntable").id]] = turntable_angle_rad
    mujoco.mj_forward(model, data)

    n_points = 0 if points_turntable is None else len(points_turntable)
    keep = (np.unique(np.linspace(0, n_points - 1, max_points).round().astype(int))
            if n_points > max_points else np.arange(n_points))
    segments = [] if lidar is None else _fan(model, data, rig, plant, lidar, fan_rays)

    camera = mujoco.MjvCamera()
    camera.type = mujoco.mjtCamera.mjCAMERA_FREE
    if view.lookat is not None:
        lookat = np.asarray(view.lookat, dtype=np.float64)
    elif plant is not None:
        lo, hi = plant.vertices_turntable.min(axis=0), plant.vertices_turntable.max(axis=0)
        lookat = (lo + hi) / 2
    else:
        lookat = np.array([rig.lidar_distance_m / 2, 0.0, rig.lidar_height_m / 2])
    camera.lookat[:] = lookat
    if view.distance_m is not None:
        camera.distance = view.distance_m
    else:
        reach = max(rig.lidar_distance_m, rig.disk_radius_m) + 0.2
        if plant is not None:
            reach = max(reach, float(np.ptp(plant.vertices_turntable, axis=0).max()))
        camera.distance = 1.9 * reach
    camera.azimuth, camera.elevation = view.azimuth_deg, view.elevation_deg

    context = _gl_context(view.width, view.height)
    try:
        mr_context = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_150)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, mr_context)
        scene = mujoco.MjvScene(model, maxgeom=model.ngeom + len(keep) + len(segments) + 100)
        option = mujoco.MjvOption()
        mujoco.mjv_updateScene(model, data, option, None, camera, mujoco.mjtCatBit.mjCAT_ALL, scene)
        R = np.array([[np.cos(turntable_angle_rad), -np.sin(turntable_angle_rad), 0],
                      [np.sin(turntable_angle_rad), np.cos(turntable_angle_rad), 0], [0, 0, 1]])
        if len(keep):
            world = points_turntable[keep] @ R.T
            rgba = (np.tile(np.array([1, 0, 1, 1], np.float32), (len(keep), 1))
                    if point_rgba is None else np.asarray(point_rgba, np.float32)[keep])
            # Points are small cubes (12 triangles each): tens of thousands of spheres would
            # need a coarse tessellation that turned the disk into a hexagon, and cost more.
            size = np.full(3, point_radius_m)
            eye = np.eye(3).ravel()
            for p, c in zip(world, rgba):
                g = scene.geoms[scene.ngeom]
                mujoco.mjv_initGeom(g, mujoco.mjtGeom.mjGEOM_BOX, size, p, eye, c)
                scene.ngeom += 1
        for start, end in segments:
            g = scene.geoms[scene.ngeom]
            mujoco.mjv_initGeom(g, mujoco.mjtGeom.mjGEOM_LINE, np.zeros(3), np.zeros(3),
                                np.eye(3).ravel(), np.array(FAN_RGBA, np.float32))
            mujoco.mjv_connector(g, mujoco.mjtGeom.mjGEOM_LINE, 2.0, start, end)
            scene.ngeom += 1
        viewport = mujoco.MjrRect(0, 0, view.width, view.height)
        mujoco.mjr_render(viewport, scene, mr_context)
        if overlay:
            mujoco.mjr_overlay(mujoco.mjtFont.mjFONT_NORMAL, mujoco.mjtGridPos.mjGRID_TOPLEFT,
                               viewport, overlay, "", mr_context)
        image = np.empty((view.height, view.width, 3), dtype=np.uint8)
        mujoco.mjr_readPixels(image, None, viewport, mr_context)
        mr_context.free()
    finally:
        context.free()
    return np.ascontiguousarray(np.flipud(image))


def png_bytes(image: np.ndarray) -> bytes:
    """An (h, w, 3) uint8 image as PNG bytes (no imaging library needed)."""
    image = np.ascontiguousarray(image, dtype=np.uint8)
    h, w = image.shape[:2]
    raw = b"".join(b"\x00" + image[row].tobytes() for row in range(h))

    def chunk(kind: bytes, body: bytes) -> bytes:
        return (len(body).to_bytes(4, "big") + kind + body
                + zlib.crc32(kind + body).to_bytes(4, "big"))

    header = w.to_bytes(4, "big") + h.to_bytes(4, "big") + bytes([8, 2, 0, 0, 0])
    out = io.BytesIO()
    out.write(b"\x89PNG\r\n\x1a\n")
    out.write(chunk(b"IHDR", header))
    out.write(chunk(b"IDAT", zlib.compress(raw, 6)))
    out.write(chunk(b"IEND", b""))
    return out.getvalue()


def _even_subsample(n: int, max_points: int) -> np.ndarray:
    """Indices of an even subsample of at most ``max_points`` of ``n`` (all when n <= max)."""
    if n <= max_points:
        return np.arange(n)
    return np.unique(np.linspace(0, n - 1, max_points).round().astype(int))


def render_cloud(cloud, rig: RigGeometry, plant=None, *, lidar=None, colour: str = "class",
                 error_max_m: float | None = None, view: View = View(),
                 **kwargs: Any) -> np.ndarray:
    """The scene with a cloud's points coloured by class or by their distance to the mesh.

    Args:
      cloud: a :class:`plantsim.cloud.reconstruct.PointCloud` (turntable frame).
      rig: rig geometry.
      plant: the placed plant (needed for ``colour="error"``).
      lidar: LidarSpec whose fan is drawn (None: no fan).
      colour: "class" or "error" (plant points only, by distance to the mesh,
        with a colour bar and its scale in the picture).
      error_max_m: the distance shown red (None: the 95th percentile).
      view: the camera.
      **kwargs: passed to :func:`render_scene`.

    Raises:
      ValueError: unknown colour, or "error" without a plant.
    """
    if colour not in ("class", "error"):
        raise ValueError(f"colour must be 'class' or 'error', got {colour!r}")
    if colour == "class":
        return render_scene(rig, plant, points_turntable=cloud.points_turntable,
                            point_rgba=_class_colours(cloud.hit_class), lidar=lidar, view=view,
                            **kwargs)
    image, _ = _render_error(cloud, rig, plant, lidar=lidar, error_max_m=error_max_m, view=view,
                             **kwargs)
    return image


def _render_error(cloud, rig, plant, *, error_max_m, view, max_points: int = 20_000, **kwargs):
    """The error picture and the distance shown red, metres."""
    if plant is None:
        raise ValueError("colour='error' needs the plant mesh the cloud was scanned from")
    pts = cloud.plant_only().points_turntable
    # Only the points drawn are measured: the picture costs the same at any step.
    pts = pts[_even_subsample(len(pts), max_points)]
    d = _distances(pts, plant)
    top = (float(np.percentile(d, 95)) if len(d) else 1e-3) if error_max_m is None else float(error_max_m)
    top = max(top, 1e-6)
    text = (f"plant points by distance to the mesh\nblue 0 mm -> red >= {top * 1e3:.3g} mm"
            + (" (p95)" if error_max_m is None else ""))
    image = render_scene(rig, plant, points_turntable=pts, point_rgba=error_colours(d, top),
                         view=view, max_points=max_points, overlay=text, **kwargs)
    return _with_colour_bar(image), top


def _with_colour_bar(image: np.ndarray) -> np.ndarray:
    """The image with the error scale's colour bar at its right edge (blue bottom, red top)."""
    h, w = image.shape[:2]
    bar_h, bar_w = max(int(0.5 * h), 2), max(w // 48, 4)
    top, left = (h - bar_h) // 2, w - 2 * bar_w
    rgb = error_colours(np.linspace(1.0, 0.0, bar_h), 1.0)[:, :3]
    out = image.copy()
    out[top:top + bar_h, left:left + bar_w] = (255 * rgb[:, None, :]).astype(np.uint8)
    return out


def _distances(points_turntable: np.ndarray, plant) -> np.ndarray:
    from plantsim.evaluation.metrics import MeshProximity

    if len(points_turntable) == 0:
        return np.zeros(0)
    return MeshProximity(plant.vertices_turntable, plant.faces).query(points_turntable).distance


def error_picture_colours(points_turntable: np.ndarray, plant,
                          error_max_m: float | None = None) -> np.ndarray:
    """(n, 4) colours of plant points by their exact distance to the plant's mesh."""
    if len(points_turntable) == 0:
        return np.zeros((0, 4), np.float32)
    d = _distances(points_turntable, plant)
    top = float(np.percentile(d, 95)) if error_max_m is None else float(error_max_m)
    return error_colours(d, max(top, 1e-6))


@dataclasses.dataclass(frozen=True)
class ErrorPicture:
    """A cloud-vs-mesh error picture.

    Attributes:
      png: the PNG file's bytes.
      error_max_m: the distance drawn red (and beyond), metres; blue is 0.
    """

    png: bytes
    error_max_m: float

    def scale_text(self) -> str:
        """The colour scale in words, for a summary line."""
        return f"blue 0 mm -> red >= {self.error_max_m * 1e3:.3g} mm"


def error_picture_of(cloud, plant, rig: RigGeometry, *, error_max_m: float | None = None,
                     view: View = View(elevation_deg=-10.0)) -> ErrorPicture:
    """The plant points coloured by distance to the true mesh, with the scale.

    The mesh is drawn too, so a point off the surface shows against it; the
    scale is written in the picture's top-left corner and drawn as a colour
    bar at its right edge. At most 20,000 points (an even subsample) are drawn
    and measured.

    Raises:
      RenderError: no offscreen OpenGL context (names what to install).
    """
    image, top = _render_error(cloud, rig, plant, error_max_m=error_max_m, view=view,
                               point_radius_m=0.001)
    return ErrorPicture(png=png_bytes(image), error_max_m=top)


def error_picture(cloud, plant, rig: RigGeometry, *, error_max_m: float | None = None,
                  view: View = View(elevation_deg=-10.0)) -> bytes:
    """PNG bytes of :func:`error_picture_of`."""
    return error_picture_of(cloud, plant, rig, error_max_m=error_max_m, view=view).png
