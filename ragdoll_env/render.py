"""Headless ray-cast renderer: one world's bodies to an RGB frame (Gymnasium ``rgb_array``).

A pinhole camera orbits a target point. Every pixel casts a ray; the nearest hit
among planes, spheres, capsules and boxes is shaded with hemispheric ambient,
Lambert and specular light from one directional light, soft shadows cast by the
bodies, and distance fog towards a sky gradient. Planes are drawn as a
box-filtered checker, so far tiles fade to grey instead of aliasing.

All work is numpy over pixels in float32. Each body only tests the rays inside
its projected screen rectangle, and the per-camera quantities (ray directions,
sky, light-space ray components) are cached until the camera angles, image size
or light change; following a moving target only moves the eye.

Units: metres, degrees for camera and light angles, RGB colours in 0..1.
Optional dependencies (pillow, pygame, matplotlib) are imported lazily.
"""

from __future__ import annotations

import math
import os
import sys
import time
from dataclasses import astuple, dataclass

import numpy as np

from engine import math3d
from engine.shapes import BOX, CAPSULE, NONE, PLANE, SPHERE

PALETTE = np.array([
    (0.86, 0.42, 0.32),
    (0.30, 0.56, 0.82),
    (0.42, 0.72, 0.44),
    (0.94, 0.74, 0.30),
    (0.62, 0.46, 0.78),
    (0.32, 0.72, 0.72),
    (0.86, 0.50, 0.64),
    (0.66, 0.62, 0.56),
])
"""Default body colours, cycled over the non-plane bodies."""

GROUND_COLOR = (0.78, 0.76, 0.72)
SKY_ZENITH = (0.42, 0.62, 0.88)
SKY_HORIZON = (0.84, 0.89, 0.94)

_NEAR = 1e-3
_F32 = np.float32
_CORNERS = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=float)


@dataclass
class Camera:
    """An orbit camera looking at a target point.

    ``azimuth_deg``: direction from the target to the eye in the ground plane,
    counter-clockwise from +x; ``elevation_deg``: angle of the eye above the
    target's horizontal plane (clamped to ±89°); ``distance``: eye to target in
    metres; ``fov_deg``: vertical field of view.
    """

    azimuth_deg: float = -60.0
    elevation_deg: float = 15.0
    distance: float = 3.5
    fov_deg: float = 45.0


@dataclass
class Style:
    """The look of a frame: one directional light plus ambient sky light,
    soft shadows, fog and the ground's checker.

    ``direction``: unit-free world vector pointing towards the light, or None
    for a light ``azimuth_offset_deg`` counter-clockwise of the camera's
    azimuth at ``elevation_deg``. ``penumbra`` is the shadow blur per metre of
    caster-to-receiver distance; ``fog_distance`` (m) is where fog hides half
    of a surface's own colour; ``checker_size`` (m) is the side of a ground
    tile.
    """

    direction: tuple | None = None
    azimuth_offset_deg: float = 60.0
    elevation_deg: float = 55.0
    ambient: float = 0.38
    ambient_sky: float = 0.12
    diffuse: float = 0.62
    specular: float = 0.25
    shininess_log2: int = 5
    penumbra: float = 0.035
    shadow_strength: float = 0.7
    fog_distance: float = 30.0
    checker_size: float = 0.5
    checker_contrast: float = 0.22


class _View:
    """Everything that depends only on the camera angles, the image size and
    the light: ray directions per pixel, the sky, the light basis."""

    def __init__(self, camera: Camera, style: Style, width: int, height: int, samples: int):
        width, height = width * samples, height * samples
        self.samples = samples
        az = math.radians(camera.azimuth_deg)
        el = math.radians(max(-89.0, min(89.0, camera.elevation_deg)))
        back = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
        self.offset = camera.distance * back
        self.forward = -back
        self.right = math3d.normalize(math3d.cross(self.forward, np.array([0.0, 0.0, 1.0])))
        self.up = math3d.cross(self.right, self.forward)
        self.width, self.height = width, height
        self.focal = 0.5 * height / math.tan(0.5 * math.radians(camera.fov_deg))

        cols = (np.arange(width) + 0.5 - 0.5 * width) / self.focal
        rows = (0.5 * height - np.arange(height) - 0.5) / self.focal
        raw = (self.forward[None, None, :] + cols[None, :, None] * self.right
               + rows[:, None, None] * self.up)
        length = np.linalg.norm(raw, axis=-1, keepdims=True)
        dirs = raw / length
        self.inv_length = (1.0 / length[..., 0]).astype(_F32)
        self.dx, self.dy, self.dz = (np.ascontiguousarray(dirs[..., k], dtype=_F32) for k in range(3))

        if style.direction is None:
            laz = az + math.radians(style.azimuth_offset_deg)
            lel = math.radians(style.elevation_deg)
            light = np.array([math.cos(lel) * math.cos(laz), math.cos(lel) * math.sin(laz), math.sin(lel)])
        else:
            light = math3d.normalize(np.asarray(style.direction, dtype=float))
        self.light = light
        helper = np.array([1.0, 0.0, 0.0]) if abs(light[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        self.light_u = math3d.normalize(math3d.cross(light, helper))
        self.light_v = math3d.cross(light, self.light_u)
        self.d_light = (dirs @ light).astype(_F32)
        self.d_lu = (dirs @ self.light_u).astype(_F32)
        self.d_lv = (dirs @ self.light_v).astype(_F32)

        up = np.clip(dirs[..., 2], 0.0, 1.0) ** 0.6
        horizon, zenith = np.asarray(SKY_HORIZON)[:, None, None], np.asarray(SKY_ZENITH)[:, None, None]
        self.sky = (horizon + up[None] * (zenith - horizon)).astype(_F32)
        self.sky255 = (255.0 * self.sky + 0.5).astype(_F32)

    def camera_coords(self, rel: np.ndarray) -> tuple[float, float, float]:
        """(right, up, forward) coordinates of a world offset from the eye."""
        return float(rel @ self.right), float(rel @ self.up), float(rel @ self.forward)

    def _rect(self, tx_lo: float, tx_hi: float, ty_lo: float, ty_hi: float):
        """Pixel rectangle (r0, r1, c0, c1) covering a range of view-plane
        tangents (x/z rightwards, y/z upwards), or None if off screen."""
        half_w, half_h = 0.5 * self.width, 0.5 * self.height
        c0 = max(0, math.floor(half_w - 0.5 + self.focal * tx_lo))
        c1 = min(self.width, math.ceil(half_w - 0.5 + self.focal * tx_hi) + 1)
        r0 = max(0, math.floor(half_h - 0.5 - self.focal * ty_hi))
        r1 = min(self.height, math.ceil(half_h - 0.5 - self.focal * ty_lo) + 1)
        return (r0, r1, c0, c1) if r0 < r1 and c0 < c1 else None

    def hull_rect(self, spheres, eye: np.ndarray):
        """Screen rectangle (r0, r1, c0, c1) bounding the convex hull of
        (centre, radius) spheres, or None if none of it can be seen."""
        coords = [(self.camera_coords(c - eye), r) for c, r in spheres]
        if all(z < -r for (_, _, z), r in coords):
            return None
        if any(z <= r + _NEAR for (_, _, z), r in coords):
            return 0, self.height, 0, self.width
        bounds = []
        for (x, y, z), r in coords:
            bounds.append(self._tangent_range(x, z, r) + self._tangent_range(y, z, r))
        bounds = np.array(bounds)
        return self._rect(bounds[:, 0].min(), bounds[:, 1].max(), bounds[:, 2].min(), bounds[:, 3].max())

    def sphere_rect(self, center: np.ndarray, radius: float, eye: np.ndarray):
        """Screen rectangle (r0, r1, c0, c1) bounding a sphere, or None if unseen."""
        return self.hull_rect(((center, radius),), eye)

    @staticmethod
    def _tangent_range(a: float, z: float, radius: float) -> tuple[float, float]:
        centre = math.atan2(a, z)
        spread = math.asin(min(1.0, radius / math.hypot(a, z)))
        lo, hi = centre - spread, centre + spread
        return (math.tan(lo) if lo > -0.5 * math.pi + 1e-6 else -1e9,
                math.tan(hi) if hi < 0.5 * math.pi - 1e-6 else 1e9)

    def points_rect(self, points: np.ndarray, eye: np.ndarray):
        """Screen rectangle bounding the convex hull of points, None if off
        screen, or "behind" if some point is not in front of the camera."""
        rel = points - eye
        x, y, z = rel @ self.right, rel @ self.up, rel @ self.forward
        if np.any(z <= _NEAR):
            return "behind"
        tx, ty = x / z, y / z
        return self._rect(tx.min(), tx.max(), ty.min(), ty.max())


def _union(a, b):
    if a is None:
        return b
    if b is None:
        return a
    return min(a[0], b[0]), max(a[1], b[1]), min(a[2], b[2]), max(a[3], b[3])


class _Buffers:
    """Per-frame G-buffer: depth (m along the ray), normal, albedo, body id."""

    def __init__(self, height: int, width: int):
        self.depth = np.full((height, width), np.inf, dtype=_F32)
        self.nx = np.zeros((height, width), dtype=_F32)
        self.ny = np.zeros((height, width), dtype=_F32)
        self.nz = np.zeros((height, width), dtype=_F32)
        self.albedo = np.zeros((3, height, width), dtype=_F32)
        self.ident = np.full((height, width), -1, dtype=np.int16)
        self.rows = (height, 0)

    def write(self, rect, t, normal, color, body: int) -> None:
        """Keep the hits ``t`` (inf: none) of ``body`` in ``rect`` = (r0, r1, c0, c1)
        that are nearer than what is there; ``color`` is (3,) or (3, h, w)."""
        r0, r1, c0, c1 = rect
        self.rows = (min(self.rows[0], r0), max(self.rows[1], r1))
        depth = self.depth[r0:r1, c0:c1]
        closer = t < depth
        np.copyto(depth, t, where=closer)
        for buf, comp in zip((self.nx, self.ny, self.nz), normal):
            np.copyto(buf[r0:r1, c0:c1], comp, where=closer)
        np.copyto(self.albedo[:, r0:r1, c0:c1], color[:, None, None] if color.ndim == 1 else color,
                  where=closer)
        np.copyto(self.ident[r0:r1, c0:c1], body, where=closer)


def _smoothstep(z):
    """Smooth 0..1 ramp of z over [-1, 1]."""
    x = np.clip(0.5 + 0.5 * z, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def _checker(p, w):
    """Box-filtered square wave (±1) of period 2 at p, filter width w (Quilez)."""
    h = 0.5 * w
    a = (p - h) * 0.5
    b = (p + h) * 0.5
    return 2.0 * (np.abs(a - np.floor(a) - 0.5) - np.abs(b - np.floor(b) - 0.5)) / w


class Renderer:
    """Ray-cast renderer of one world of a scene.

    ``shape_type`` (N,) and ``shape_params`` (N, 3) follow :mod:`engine.shapes`.
    ``colors`` is an (N, 3) RGB array in 0..1 (plane entries tint the checker);
    by default bodies cycle through :data:`PALETTE` and planes are light grey.
    The camera is ``self.camera`` (a :class:`Camera`; ``azimuth``,
    ``elevation``, ``distance`` are shortcuts to it), light, shadows, fog
    and ground pattern are ``self.style`` (a :class:`Style`), and
    ``supersample`` (default 1) renders s×s rays per pixel for smooth edges
    at s² times the cost.
    """

    def __init__(self, shape_type, shape_params, width: int = 640, height: int = 480,
                 colors=None, fov_deg: float = 45.0):
        self.shape_type = np.asarray(shape_type, dtype=np.int64).reshape(-1)
        n = self.shape_type.size
        self.shape_params = np.asarray(shape_params, dtype=float).reshape(n, 3)
        if int(width) < 1 or int(height) < 1:
            raise ValueError(f"width and height must be >= 1, got {width}x{height}")
        self.width, self.height = int(width), int(height)
        self.colors = self._default_colors() if colors is None else self._check_colors(colors)
        self.camera = Camera(fov_deg=float(fov_deg))
        self.style = Style()
        self._view_cache: tuple | None = None
        self.planes = np.flatnonzero(self.shape_type == PLANE)
        self._is_solid = np.isin(self.shape_type, (SPHERE, CAPSULE, BOX))
        self.solids = np.flatnonzero(self._is_solid)
        self.supersample = 1

    @classmethod
    def from_model(cls, model, **kwargs) -> "Renderer":
        """A renderer for an :class:`engine.model.Model`'s shapes."""
        return cls(model.shape_type, model.shape_params, **kwargs)

    @property
    def azimuth(self) -> float:
        """Camera azimuth in degrees (direction target -> eye, counter-clockwise from +x)."""
        return self.camera.azimuth_deg

    @azimuth.setter
    def azimuth(self, degrees: float) -> None:
        self.camera.azimuth_deg = float(degrees)

    @property
    def elevation(self) -> float:
        """Camera elevation above the target's horizontal plane, degrees."""
        return self.camera.elevation_deg

    @elevation.setter
    def elevation(self, degrees: float) -> None:
        self.camera.elevation_deg = float(degrees)

    @property
    def distance(self) -> float:
        """Eye-to-target distance, metres."""
        return self.camera.distance

    @distance.setter
    def distance(self, metres: float) -> None:
        self.camera.distance = float(metres)

    def _default_colors(self) -> np.ndarray:
        colors = np.empty((self.shape_type.size, 3))
        k = 0
        for i, code in enumerate(self.shape_type):
            if code == PLANE:
                colors[i] = GROUND_COLOR
            else:
                colors[i] = PALETTE[k % len(PALETTE)]
                k += code != NONE
        return colors

    def _check_colors(self, colors) -> np.ndarray:
        colors = np.asarray(colors, dtype=float)
        if colors.shape != (self.shape_type.size, 3):
            raise ValueError(f"colors must have shape ({self.shape_type.size}, 3), got {colors.shape}")
        return np.clip(colors, 0.0, 1.0)

    def _view(self, camera: Camera) -> _View:
        samples = int(self.supersample)
        if samples < 1:
            raise ValueError(f"supersample must be an integer >= 1, got {self.supersample!r}")
        key = (astuple(camera), astuple(self.style), self.width, self.height, samples)
        if self._view_cache is None or self._view_cache[0] != key:
            self._view_cache = (key, _View(camera, self.style, self.width, self.height, samples))
        return self._view_cache[1]

    # ------------------------------------------------------------------ frame
    def _pose(self, positions, orientations):
        n = self.shape_type.size
        pos = np.asarray(positions, dtype=float)
        quat = np.asarray(orientations, dtype=float)
        if pos.size != 3 * n or quat.size != 4 * n:
            raise ValueError(f"expected positions ({n}, 3) and orientations ({n}, 4) for {n} bodies, "
                             f"got {pos.shape} and {quat.shape}")
        return pos.reshape(n, 3), quat.reshape(n, 4)

    def project(self, points, target, camera: Camera | None = None) -> np.ndarray:
        """Pixel coordinates (..., 2) as (column, row), fractional, of world
        points (..., 3) m for a camera looking at ``target``; NaN for points
        not in front of the camera."""
        cam = self.camera if camera is None else camera
        view = self._view(cam)
        rel = np.asarray(points, dtype=float) - (np.asarray(target, dtype=float) + view.offset)
        x, y, z = rel @ view.right, rel @ view.up, rel @ view.forward
        z = np.where(z > _NEAR, z, np.nan)
        focal = view.focal / view.samples
        return np.stack((0.5 * self.width + focal * x / z, 0.5 * self.height - focal * y / z), axis=-1)

    def default_target(self, positions) -> np.ndarray:
        """Mean position (m) of the finite solid bodies, or the origin."""
        pos = np.asarray(positions, dtype=float).reshape(-1, 3)[self.solids]
        pos = pos[np.all(np.isfinite(pos), axis=1)]
        return pos.mean(axis=0) if len(pos) else np.zeros(3)

    def render(self, positions, orientations, target=None, camera: Camera | None = None) -> np.ndarray:
        """RGB frame (height, width, 3) uint8 of one world's pose.

        ``positions`` (N, 3) metres and ``orientations`` (N, 4) unit (w, x, y, z)
        quaternions, or the same with a leading world axis of size 1. The camera
        looks at ``target`` (default :meth:`default_target`) from ``camera``
        (default ``self.camera``). Bodies with a non-finite pose are skipped.
        """
        pos, quat = self._pose(positions, orientations)
        n = self.shape_type.size
        view = self._view(self.camera if camera is None else camera)
        target = self.default_target(pos) if target is None else np.asarray(target, dtype=float).reshape(3)
        eye = target + view.offset
        ok = np.all(np.isfinite(pos), axis=1) & np.all(np.isfinite(quat), axis=1)
        rot = np.zeros((n, 3, 3))
        rot[ok] = math3d.quat_to_matrix(math3d.quat_normalize(quat[ok]))

        buf = _Buffers(view.height, view.width)
        for i in self.planes:
            if ok[i]:
                self._draw_plane(view, buf, eye, pos[i], rot[i], i)
        drawn, body_rect = [], None
        for i in self.solids:
            if ok[i]:
                rect = self._draw_solid(view, buf, eye, pos[i], rot[i], i)
                if rect is not None:
                    body_rect = _union(body_rect, rect)
                drawn.append(i)
        visibility = self._shadows(view, buf, eye, pos, rot, ok, drawn)
        return self._shade(view, buf, visibility, body_rect)

    # ----------------------------------------------------------------- planes
    def _draw_plane(self, view: _View, buf: _Buffers, eye, origin, rot, body: int) -> None:
        """Ray-plane hits on the rows that see the plane, with a checker filtered
        over each pixel's footprint (ray differentials along both screen axes)."""
        normal, e1, e2 = rot[:, 2], rot[:, 0], rot[:, 1]
        height = float((eye - origin) @ normal)
        sign = 1.0 if height >= 0.0 else -1.0
        dn = view.dx * _F32(normal[0]) + view.dy * _F32(normal[1]) + view.dz * _F32(normal[2])
        toward = dn * _F32(sign) < 0.0
        rows = np.flatnonzero(toward.any(axis=1))
        if rows.size == 0:
            return
        r0, r1 = int(rows[0]), int(rows[-1]) + 1
        dn, toward = dn[r0:r1], toward[r0:r1]
        inv_dn = _F32(1.0) / np.where(toward, dn, _F32(-sign))
        t = np.where(toward, _F32(-height) * inv_dn, _F32(0.0))

        size = self.style.checker_size
        rel = (eye - origin) / size
        scale = t * view.inv_length[r0:r1] * _F32(1.0 / (view.focal * size))
        rn, un = float(view.right @ normal), float(view.up @ normal)
        check = None
        for e in (e1, e2):
            de = view.dx[r0:r1] * _F32(e[0]) + view.dy[r0:r1] * _F32(e[1]) + view.dz[r0:r1] * _F32(e[2])
            p = _F32(rel @ e) + t * de * _F32(1.0 / size)
            slope = de * inv_dn
            width = np.abs(_F32(view.right @ e) - slope * _F32(rn)) + np.abs(_F32(view.up @ e) - slope * _F32(un))
            width *= scale
            width += _F32(1e-4)
            wave = _checker(p, width)
            check = wave if check is None else check * wave
        contrast = 0.5 * self.style.checker_contrast
        shade = _F32(1.0 - contrast) + _F32(contrast) * check
        color = self.colors[body].astype(_F32)[:, None, None] * shade
        depth = np.where(toward, t, _F32(np.inf))
        buf.write((r0, r1, 0, view.width), depth, tuple(_F32(sign * c) for c in normal), color, body)

    # ----------------------------------------------------------------- solids
    def _solid_rect(self, view: _View, eye, center, rot, code, params):
        if code == SPHERE:
            return view.sphere_rect(center, params[0], eye)
        if code == CAPSULE:
            axis = rot[:, 2] * params[1]
            return view.hull_rect(((center - axis, params[0]), (center + axis, params[0])), eye)
        rect = view.points_rect(center + (_CORNERS * params) @ rot.T, eye)
        if rect == "behind":
            return view.sphere_rect(center, float(np.linalg.norm(params)), eye)
        return rect

    def _draw_solid(self, view: _View, buf: _Buffers, eye, center, rot, body: int):
        code, params = self.shape_type[body], self.shape_params[body]
        rect = self._solid_rect(view, eye, center, rot, code, params)
        if rect is None:
            return None
        r0, r1, c0, c1 = rect
        d = (view.dx[r0:r1, c0:c1], view.dy[r0:r1, c0:c1], view.dz[r0:r1, c0:c1])
        if code == SPHERE:
            t, normal = _hit_sphere(d, eye - center, params[0])
        elif code == CAPSULE:
            t, normal = _hit_capsule(d, eye - center, rot[:, 2], params[0], params[1])
        else:
            t, normal = _hit_box(d, eye - center, rot, params)
        buf.write(rect, t, normal, self.colors[body].astype(_F32), body)
        return rect

    # ---------------------------------------------------------------- shadows
    def _shadows(self, view: _View, buf: _Buffers, eye, pos, rot, ok, drawn) -> np.ndarray:
        """Light visibility per pixel in 0..1 from the bodies' soft shadows.

        A receiver point is shadowed by a body when the ray from it towards the
        light passes through the body; the miss distance over a width growing
        with the distance to the body gives the penumbra. Work per body is
        limited to the screen rectangle of its shadow volume down to the ground.
        """
        vis = np.ones((view.height, view.width), dtype=_F32)
        light, k = view.light, self.style.penumbra
        ground = [(pos[i], rot[i][:, 2]) for i in self.planes if ok[i] and rot[i][:, 2] @ light > 0.05]
        casters, area = [], None
        for i in drawn:
            code, params = self.shape_type[i], self.shape_params[i]
            radius = {SPHERE: params[0], CAPSULE: params[0] + params[1]}.get(code, float(np.linalg.norm(params)))
            reach, spread = min(self._ground_distances(pos[i], light, ground), default=(4.0, 1.0))
            rect = view.hull_rect(((pos[i], radius),
                                   (pos[i] - light * reach, radius * spread + k * reach + 0.01)), eye)
            if rect is not None:
                casters.append((i, rect))
                area = _union(area, rect)
        if area is None:
            return vis
        a0, a1, b0, b1 = area
        seen = np.isfinite(buf.depth[a0:a1, b0:b1])
        t = np.where(seen, buf.depth[a0:a1, b0:b1], _F32(0.0))
        coords = [_F32(eye @ axis) + t * d[a0:a1, b0:b1]
                  for axis, d in ((view.light_u, view.d_lu), (view.light_v, view.d_lv), (light, view.d_light))]
        for i, (r0, r1, c0, c1) in casters:
            sl = (slice(r0, r1), slice(c0, c1))
            local = (slice(r0 - a0, r1 - a0), slice(c0 - b0, c1 - b0))
            receiver = seen[local] & (buf.ident[sl] != i)
            if not receiver.any():
                continue
            pts = tuple(c[local] for c in coords)
            code, params = self.shape_type[i], self.shape_params[i]
            if code == SPHERE:
                v = self._sphere_shadow(view, pts, pos[i], params[0], k)
            elif code == CAPSULE:
                axis = rot[i][:, 2] * params[1]
                v = self._capsule_shadow(view, pts, pos[i] - axis, pos[i] + axis, params[0], k)
            else:
                v = self._box_shadow(view, pts, pos[i], rot[i], params, k)
            np.minimum(vis[sl], v, out=vis[sl], where=receiver)
        strength = _F32(self.style.shadow_strength)
        vis -= _F32(1.0)
        vis *= strength
        vis += _F32(1.0)
        return vis

    @staticmethod
    def _ground_distances(point, light, ground):
        """(distance along -light from point to a plane, 1/cos of the light on it) per plane."""
        for origin, normal in ground:
            cos = float(normal @ light)
            s = float((point - origin) @ normal) / cos
            if s > 0.0:
                yield s, 1.0 / cos

    @staticmethod
    def _light_coords(view: _View, p) -> tuple[float, float, float]:
        return float(p @ view.light_u), float(p @ view.light_v), float(p @ view.light)

    def _sphere_shadow(self, view, pts, center, radius, k):
        cu, cv, cw = self._light_coords(view, center)
        u, v, w = pts
        du, dv = u - _F32(cu), v - _F32(cv)
        ahead = _F32(cw) - w
        gap = np.sqrt(du * du + dv * dv) - _F32(radius)
        width = _F32(k) * np.maximum(ahead, _F32(0.0)) + _F32(0.004)
        return np.where(ahead > 0.0, _smoothstep(gap / width), _F32(1.0))

    def _capsule_shadow(self, view, pts, a, b, radius, k):
        au, av, aw = self._light_coords(view, a)
        bu, bv, bw = self._light_coords(view, b)
        eu, ev, ew = bu - au, bv - av, bw - aw
        ee = max(eu * eu + ev * ev, 1e-12)
        u, v, w = pts
        pu, pv = u - _F32(au), v - _F32(av)
        h = np.clip((pu * _F32(eu) + pv * _F32(ev)) * _F32(1.0 / ee), 0.0, 1.0)
        qu, qv = pu - h * _F32(eu), pv - h * _F32(ev)
        ahead = _F32(aw) + h * _F32(ew) - w
        gap = np.sqrt(qu * qu + qv * qv) - _F32(radius)
        width = _F32(k) * np.maximum(ahead, _F32(0.0)) + _F32(0.004)
        return np.where(ahead > 0.0, _smoothstep(gap / width), _F32(1.0))

    def _box_shadow(self, view, pts, center, rot, half, k):
        u, v, w = pts
        cu, cv, cw = self._light_coords(view, center)
        du, dv, dw = u - _F32(cu), v - _F32(cv), w - _F32(cw)
        basis_u, basis_v, basis_l = rot.T @ view.light_u, rot.T @ view.light_v, rot.T @ view.light
        near = far = None
        for j in range(3):
            local = du * _F32(basis_u[j]) + dv * _F32(basis_v[j]) + dw * _F32(basis_l[j])
            step = basis_l[j]
            if abs(step) < 1e-9:
                inside = np.abs(local) <= _F32(half[j])
                lo = np.where(inside, _F32(-1e30), _F32(1e30))
                hi = -lo
            else:
                t1 = (_F32(-half[j]) - local) * _F32(1.0 / step)
                t2 = (_F32(half[j]) - local) * _F32(1.0 / step)
                lo, hi = np.minimum(t1, t2), np.maximum(t1, t2)
            near = lo if near is None else np.maximum(near, lo)
            far = hi if far is None else np.minimum(far, hi)
        mid = 0.5 * (near + far)
        width = _F32(k) * np.maximum(mid, _F32(0.0)) + _F32(0.004)
        return np.where(far > 0.0, _smoothstep((near - far) / width), _F32(1.0))

    # ---------------------------------------------------------------- shading
    def _shade(self, view: _View, buf: _Buffers, vis: np.ndarray, body_rect) -> np.ndarray:
        """Light the G-buffer rows that saw a surface, fog them towards the sky,
        average supersamples and return the uint8 (height, width, 3) frame."""
        lit = self.style
        color = view.sky255.copy()
        r0, r1 = buf.rows
        if r0 < r1:
            rows = slice(r0, r1)
            nx, ny, nz = buf.nx[rows], buf.ny[rows], buf.nz[rows]
            L = view.light
            ndl = nx * _F32(L[0]) + ny * _F32(L[1]) + nz * _F32(L[2])
            light = _F32(lit.ambient) + _F32(lit.ambient_sky) * nz
            light += _F32(lit.diffuse) * np.maximum(ndl, _F32(0.0)) * vis[rows]
            lit_color = buf.albedo[:, rows] * light
            if body_rect is not None:
                self._add_specular(view, buf, vis, ndl, lit_color, body_rect, r0)
            keep = buf.depth[rows] * _F32(1.0 / lit.fog_distance)
            keep *= keep
            keep += _F32(1.0)
            np.divide(_F32(255.0), keep, out=keep)
            lit_color -= view.sky[:, rows]
            lit_color *= keep
            color[:, rows] += lit_color
        if view.samples > 1:
            s = view.samples
            color = color.reshape(3, self.height, s, self.width, s).mean(axis=(2, 4))
        np.minimum(color, _F32(255.0), out=color)
        planes = color.astype(np.uint8)
        return np.stack((planes[0], planes[1], planes[2]), axis=-1)

    def _add_specular(self, view, buf, vis, ndl, lit_color, rect, row0) -> None:
        """Phong highlights on the solid bodies inside ``rect``."""
        lit = self.style
        r0, r1, c0, c1 = rect
        sl = (slice(r0, r1), slice(c0, c1))
        local = (slice(r0 - row0, r1 - row0), slice(c0, c1))
        dn = view.dx[sl] * buf.nx[sl] + view.dy[sl] * buf.ny[sl] + view.dz[sl] * buf.nz[sl]
        refl = np.maximum(view.d_light[sl] - _F32(2.0) * dn * ndl[local], _F32(0.0))
        for _ in range(lit.shininess_log2):
            refl *= refl
        refl *= vis[sl]
        refl *= _F32(lit.specular)
        solid = buf.ident[sl] >= 0
        solid &= self._is_solid[np.maximum(buf.ident[sl], 0)]
        np.add(lit_color[(slice(None),) + local], refl, out=lit_color[(slice(None),) + local], where=solid)


# --------------------------------------------------------------- ray casts
def _hit_sphere(d, rel, radius):
    """Ray distance (inf on a miss) and unit normal for rays d from eye offset rel = eye - centre."""
    dx, dy, dz = d
    ox, oy, oz = (_F32(c) for c in rel)
    b = dx * ox + dy * oy + dz * oz
    disc = b * b - _F32(rel @ rel - radius * radius)
    t = -b - np.sqrt(np.maximum(disc, _F32(0.0)))
    hit = (disc >= 0.0) & (t > _NEAR)
    ts = np.where(hit, t, _F32(0.0))
    inv = _F32(1.0 / radius)
    normal = ((ox + ts * dx) * inv, (oy + ts * dy) * inv, (oz + ts * dz) * inv)
    return np.where(hit, t, _F32(np.inf)), normal


def _hit_capsule(d, rel, axis, radius, half_length):
    """Capsule from -half_length to +half_length along unit ``axis`` (Quilez's capsule test)."""
    dx, dy, dz = d
    ba = 2.0 * half_length * axis
    oa = rel + half_length * axis
    baba = float(ba @ ba)
    baoa = float(ba @ oa)
    bard = dx * _F32(ba[0]) + dy * _F32(ba[1]) + dz * _F32(ba[2])
    rdoa = dx * _F32(oa[0]) + dy * _F32(oa[1]) + dz * _F32(oa[2])
    a = _F32(baba) - bard * bard
    b = _F32(baba) * rdoa - _F32(baoa) * bard
    c = baba * float(oa @ oa) - baoa * baoa - radius * radius * baba
    h = b * b - a * _F32(c)
    side = a > _F32(1e-9 * baba)
    t_side = (-b - np.sqrt(np.maximum(h, _F32(0.0)))) / np.where(side, a, _F32(1.0))
    y = np.where(side, _F32(baoa) + t_side * bard, -bard)
    on_side = side & (y > 0.0) & (y < _F32(baba))
    low = y <= 0.0
    bc = np.where(low, rdoa, rdoa - bard)
    cc = np.where(low, _F32(oa @ oa - radius * radius), _F32((oa - ba) @ (oa - ba) - radius * radius))
    hc = bc * bc - cc
    t_cap = -bc - np.sqrt(np.maximum(hc, _F32(0.0)))
    t = np.where(on_side, t_side, t_cap)
    hit = (h >= 0.0) & (on_side | (hc >= 0.0)) & (t > _NEAR)
    ts = np.where(hit, t, _F32(0.0))
    k = np.clip((_F32(baoa) + ts * bard) * _F32(1.0 / baba), 0.0, 1.0)
    inv = _F32(1.0 / radius)
    normal = tuple((_F32(oa[j]) + ts * dj - k * _F32(ba[j])) * inv for j, dj in enumerate(d))
    return np.where(hit, t, _F32(np.inf)), normal


def _hit_box(d, rel, rot, half):
    """Slab test in the box frame; ``rot`` maps box to world axes."""
    dx, dy, dz = d
    origin = rot.T @ rel
    near = far = None
    faces = []
    with np.errstate(divide="ignore", invalid="ignore"):
        for j in range(3):
            local = dx * _F32(rot[0, j]) + dy * _F32(rot[1, j]) + dz * _F32(rot[2, j])
            inv = _F32(1.0) / local
            t1 = _F32(-half[j] - origin[j]) * inv
            t2 = _F32(half[j] - origin[j]) * inv
            lo, hi = np.minimum(t1, t2), np.maximum(t1, t2)
            faces.append((lo, local))
            near = lo if near is None else np.maximum(near, lo)
            far = hi if far is None else np.minimum(far, hi)
    hit = (near <= far) & (near > _NEAR)
    normal = [np.zeros_like(near) for _ in range(3)]
    for j, (lo, local) in enumerate(faces):
        coef = np.where(lo == near, np.where(local < 0.0, _F32(1.0), _F32(-1.0)), _F32(0.0))
        for k in range(3):
            normal[k] += coef * _F32(rot[k, j])
    return np.where(hit, near, _F32(np.inf)), tuple(normal)


# ------------------------------------------------------------------ output
def save_png(frame: np.ndarray, path) -> str:
    """Write an (H, W, 3) uint8 frame to ``path`` as PNG (needs pillow)."""
    try:
        from PIL import Image
    except ImportError as exc:
        raise ImportError("save_png needs pillow: pip install pillow") from exc
    frame = np.asarray(frame)
    if frame.ndim != 3 or frame.shape[2] not in (3, 4) or frame.dtype != np.uint8:
        raise ValueError(f"frame must be (H, W, 3) uint8, got {frame.shape} {frame.dtype}")
    Image.fromarray(frame).save(os.fspath(path), format="PNG")
    return os.fspath(path)


def frame_strip(frames, path, columns: int | None = None, gap: int = 4, background=255) -> np.ndarray:
    """Tile equally sized frames row by row, ``columns`` per row (default: all
    in one row), ``gap`` pixels apart, write the grid to ``path`` as PNG and
    return it."""
    frames = [np.asarray(f) for f in frames]
    if not frames:
        raise ValueError("frame_strip needs at least one frame")
    shape = frames[0].shape
    if any(f.shape != shape for f in frames):
        raise ValueError("all frames must have the same shape")
    cols = len(frames) if columns is None else max(1, min(int(columns), len(frames)))
    rows = -(-len(frames) // cols)
    h, w = shape[:2]
    grid = np.full((rows * h + (rows - 1) * gap, cols * w + (cols - 1) * gap) + shape[2:],
                   background, dtype=np.uint8)
    for k, f in enumerate(frames):
        r, c = divmod(k, cols)
        grid[r * (h + gap):r * (h + gap) + h, c * (w + gap):c * (w + gap) + w] = f
    save_png(grid, path)
    return grid


# ------------------------------------------------------------------ window
def display_available() -> bool:
    """Whether a window can be opened: on Linux, DISPLAY or WAYLAND_DISPLAY is set."""
    if sys.platform.startswith("linux"):
        return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    return True


def open_human_viewer(title: str, fps: float | None = None):
    """The window of ``render_mode="human"``, or None (with a warning) when
    no display is available: a headless process keeps stepping and rendering
    calls return None, as Gymnasium's checker expects of every declared mode."""
    if not display_available():
        import warnings

        warnings.warn(f"{title}: render_mode='human' without a display (neither DISPLAY nor "
                      "WAYLAND_DISPLAY is set); frames are not shown. Use render_mode='rgb_array' "
                      "headless", RuntimeWarning, stacklevel=3)
        return None
    return HumanViewer(title=title, fps=fps)


class HumanViewer:
    """A window showing frames (Gymnasium ``render_mode="human"``).

    Uses pygame if importable, else matplotlib's interactive mode. ``fps``
    (frames per second, optional) paces :meth:`show` to real time. Raises
    RuntimeError at construction when no display is available.
    """

    def __init__(self, title: str = "ragdoll", fps: float | None = None):
        if not display_available():
            raise RuntimeError("render_mode='human' needs a display, but neither DISPLAY nor "
                               "WAYLAND_DISPLAY is set; use render_mode='rgb_array' headless")
        self.title, self.fps = title, fps
        self._backend = None
        self._window = None
        self._last = None
        self.closed = False

    def _open(self, frame: np.ndarray) -> None:
        try:
            import pygame
        except ImportError:
            pygame = None
        if pygame is not None:
            pygame.display.init()
            self._window = pygame.display.set_mode((frame.shape[1], frame.shape[0]))
            pygame.display.set_caption(self.title)
            self._backend = pygame
            return
        try:
            import matplotlib.pyplot as plt
        except ImportError as exc:
            raise RuntimeError("render_mode='human' needs pygame or matplotlib: pip install pygame") from exc
        if plt.get_backend().lower() in ("agg", "pdf", "svg", "ps", "cairo", "template"):
            raise RuntimeError(f"matplotlib backend {plt.get_backend()!r} cannot open a window; "
                               "install pygame or set MPLBACKEND to an interactive backend")
        plt.ion()
        fig, ax = plt.subplots(num=self.title)
        ax.set_axis_off()
        fig.subplots_adjust(0, 0, 1, 1)
        self._window = (plt, fig, ax.imshow(frame))
        self._backend = "matplotlib"

    def show(self, frame: np.ndarray) -> None:
        """Display an (H, W, 3) uint8 frame."""
        if self.closed:
            return
        frame = np.asarray(frame)
        if self._backend is None:
            self._open(frame)
        if self._backend == "matplotlib":
            plt, fig, image = self._window
            image.set_data(frame)
            fig.canvas.draw_idle()
            plt.pause(0.001)
        else:
            pygame = self._backend
            for event in pygame.event.get():
                if event.type == pygame.QUIT:
                    self.close()
                    return
            pygame.surfarray.blit_array(self._window, frame.swapaxes(0, 1))
            pygame.display.flip()
        if self.fps:
            now = time.perf_counter()
            if self._last is not None:
                time.sleep(max(0.0, 1.0 / self.fps - (now - self._last)))
            self._last = time.perf_counter()

    def close(self) -> None:
        """Close the window (idempotent)."""
        if self._backend == "matplotlib":
            plt, fig, _ = self._window
            plt.close(fig)
        elif self._backend is not None:
            self._backend.display.quit()
        self._backend = None
        self.closed = True
