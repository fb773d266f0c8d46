"""Counting a target body's pixels in a label camera's image by rendering only the region the body can cover.

Search observes the number of target-block pixels in the 128 x 128 top-down label image (FACTS.md). The
camera renders on the CPU (VTK on Mesa's software rasterizer), where the geometries drawn cost more than the
pixels: the whole image of the Search scene (72 blocks, the robot) took 12-18 ms, ~8 % of a Search step.
Only the target's pixels are counted, so :class:`TargetPixelCounter` renders just the sub-window of the image
that the box around the target projects into (padded by a pixel; Drake's ``CameraInfo`` also wants the
principal point inside it), with the same focal lengths and the principal point shifted by the window's
offset: the same pixels along the same rays, occluders in front of the target included. That render took
~6-7 ms where the whole image took 12-14 ms (``/tmp`` diagnostic, 96 Search states). The two projections
are the same up to floating-point rounding, which could flip a pixel on a triangle's edge; the tests compare
the counts with the whole image's on many states (equal in all so far). A target whose box projects outside
the image has 0 pixels and costs no render.
"""

import math

import numpy as np
from pydrake.geometry import (
    Box,
    Capsule,
    ColorRenderCamera,
    Convex,
    Cylinder,
    Ellipsoid,
    FrameId,
    Mesh,
    QueryObject,
    RenderCameraCore,
    Role,
    SceneGraph,
    SceneGraphInspector,
    Sphere,
)
from pydrake.math import RigidTransform
from pydrake.systems.sensors import CameraInfo, RgbdSensor

CACHE_SIZE = 256
"""Sub-window cameras and target boxes kept for reuse (a target moving slowly projects into the same few
windows); beyond it the cache starts over."""


def _shape_points(shape) -> np.ndarray:
    """(n, 3) points in the geometry frame whose bounding box contains ``shape``."""
    if isinstance(shape, (Mesh, Convex)):
        hull = shape.GetConvexHull()
        return np.array([hull.vertex(i) for i in range(hull.num_vertices())])
    if isinstance(shape, Box):
        half = np.array([shape.width(), shape.depth(), shape.height()]) / 2
    elif isinstance(shape, Sphere):
        half = np.full(3, shape.radius())
    elif isinstance(shape, Ellipsoid):
        half = np.array([shape.a(), shape.b(), shape.c()])
    elif isinstance(shape, Cylinder):
        half = np.array([shape.radius(), shape.radius(), shape.length() / 2])
    elif isinstance(shape, Capsule):
        half = np.array([shape.radius(), shape.radius(), shape.length() / 2 + shape.radius()])
    else:
        raise ValueError(f"TargetPixelCounter: no bounds for a perception shape of type {type(shape).__name__}")
    return np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * half


def box_corners(points: np.ndarray) -> list[list[float]]:
    """The 8 corners of the axis-aligned box around ``points`` (n, 3)."""
    low, high = points.min(axis=0), points.max(axis=0)
    return [[x, y, z] for x in (low[0], high[0]) for y in (low[1], high[1]) for z in (low[2], high[2])]


class TargetPixelCounter:
    """Counts the pixels of one render label in a label camera's image, rendering only the target's region.

    The target's extent is read per count from the query object's inspector (its perception geometries' shapes
    and poses), so geometry changed in the context (domain randomization's object scale) is followed.

    Args:
        camera: the label camera (e.g. ``RgbdSensor.default_color_render_camera()``; its renderer renders
            labels).
        parent_frame_id: the frame the camera is mounted on (``RgbdSensor.default_parent_frame_id()``).
        X_PB: the camera body's pose in that frame (``RgbdSensor.default_X_PB()``).
    """

    def __init__(self, camera: ColorRenderCamera, parent_frame_id: FrameId, X_PB: RigidTransform):
        core = camera.core()
        self._core, self._parent, self._X_PB = core, parent_frame_id, X_PB
        self._intrinsics = core.intrinsics()
        self._X_PC = X_PB @ core.sensor_pose_in_camera_body()  # The optical frame C (z forward, y down).
        is_world = parent_frame_id == SceneGraph.world_frame_id()
        self._X_CW = self._X_PC.inverse().GetAsMatrix34().tolist() if is_world else None  # Else per count.
        self._near = core.clipping().near()
        self._cameras = {}  # (u0, v0, width, height) -> the sub-window's camera (at most CACHE_SIZE).
        self._corners = {}  # The perception geometries' (shape, pose) -> their box's corners (at most CACHE_SIZE).

    @staticmethod
    def from_sensor(sensor: RgbdSensor) -> "TargetPixelCounter":
        """The counter for an RgbdSensor's label images (its default camera, parent frame and pose)."""
        return TargetPixelCounter(sensor.default_color_render_camera(), sensor.default_parent_frame_id(),
                                  sensor.default_X_PB())

    def region(self, X_CB: list[list[float]], corners: list[list[float]]) -> tuple[int, int, int, int] | None:
        """The sub-window (u0, v0, u1, v1), ends exclusive, holding the projection of the box ``corners``
        (in body frame B) for the body's pose ``X_CB`` in the optical frame (3 rows of floats); None if it
        misses the image, the whole image if a corner is not in front of the near plane."""
        info = self._intrinsics
        width, height, fx, fy, cx, cy = (info.width(), info.height(), info.focal_x(), info.focal_y(),
                                         info.center_x(), info.center_y())
        (r00, r01, r02, px), (r10, r11, r12, py), (r20, r21, r22, pz) = X_CB
        us, vs = [], []
        for x, y, z in corners:
            depth = r20 * x + r21 * y + r22 * z + pz
            if depth <= self._near:
                return 0, 0, width, height
            us.append(fx * (r00 * x + r01 * y + r02 * z + px) / depth + cx)
            vs.append(fy * (r10 * x + r11 * y + r12 * z + py) / depth + cy)
        u0, u1 = max(math.floor(min(us)) - 1, 0), min(math.ceil(max(us)) + 2, width)
        v0, v1 = max(math.floor(min(vs)) - 1, 0), min(math.ceil(max(vs)) + 2, height)
        if u0 >= u1 or v0 >= v1:
            return None
        # Drake's CameraInfo wants the principal point strictly inside the window.
        return (min(u0, math.ceil(cx) - 1), min(v0, math.ceil(cy) - 1),
                max(u1, math.floor(cx) + 1), max(v1, math.floor(cy) + 1))

    def count(self, query_object: QueryObject, label: int, frame_id: FrameId, X_WB: list[list[float]]) -> int:
        """Pixels of render label ``label`` in the camera's label image: those of the body on frame ``frame_id``
        (its perception geometry), at pose ``X_WB`` (3 rows of floats [R | p]; the frame's pose in the
        query object's state)."""
        corners = self.corners(query_object.inspector(), frame_id)
        if not corners:
            return 0
        X_CW = self._X_CW
        if X_CW is None:
            X_WP = query_object.GetPoseInWorld(self._parent)
            X_CW = (X_WP @ self._X_PC).inverse().GetAsMatrix34().tolist()
        columns = list(zip(*X_WB, strict=True))  # X_CB = X_CW X_WB, on 3 x 4 rows (the last row 0 0 0 1).
        X_CB = [[c0 * b0 + c1 * b1 + c2 * b2 for b0, b1, b2 in columns] for c0, c1, c2, _ in X_CW]
        for row, (*_, c3) in zip(X_CB, X_CW, strict=True):
            row[3] += c3
        window = self.region(X_CB, corners)
        if window is None:
            return 0
        image = query_object.RenderLabelImage(self._camera(window), self._parent, self._X_PB)
        return int(np.count_nonzero(image.data == label))

    def corners(self, inspector: SceneGraphInspector, frame_id: FrameId) -> list[list[float]]:
        """The 8 corners, in the frame, of the axis-aligned box around the perception geometry on ``frame_id``
        (empty if it has none), for the shapes and poses ``inspector`` has now."""
        geometries = inspector.GetGeometries(frame_id, Role.kPerception)
        shapes = [inspector.GetShape(g) for g in geometries]
        poses = [inspector.GetPoseInFrame(g).GetAsMatrix34() for g in geometries]
        key = tuple((repr(shape), pose.tobytes()) for shape, pose in zip(shapes, poses, strict=True))
        if key not in self._corners:
            if len(self._corners) >= CACHE_SIZE:
                self._corners.clear()
            points = [_shape_points(shape) @ X_FG[:, :3].T + X_FG[:, 3] for shape, X_FG in zip(shapes, poses,
                                                                                               strict=True)]
            self._corners[key] = box_corners(np.vstack(points)) if points else []
        return self._corners[key]

    def _camera(self, window: tuple[int, int, int, int]) -> ColorRenderCamera:
        u0, v0, u1, v1 = window
        key = (u0, v0, u1 - u0, v1 - v0)
        if key not in self._cameras:
            if len(self._cameras) >= CACHE_SIZE:
                self._cameras.clear()
            info, core = self._intrinsics, self._core
            sub = CameraInfo(u1 - u0, v1 - v0, info.focal_x(), info.focal_y(), info.center_x() - u0,
                             info.center_y() - v0)
            self._cameras[key] = ColorRenderCamera(RenderCameraCore(core.renderer_name(), sub, core.clipping(),
                                                                    core.sensor_pose_in_camera_body()), False)
        return self._cameras[key]
