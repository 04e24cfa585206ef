"""Render textured, shaded synthetic faces into pinhole-camera images (eq. 1 and 2 made visible).

A frame is rendered in five steps:

1. the dense head surface follows the 34 true nodes (:mod:`~face_tracking_ros.synthetic.surface`)
   and is moved into the camera frame by eq. 1, ``X_c = R(omega) X + t``;
2. front-facing triangles are rasterised far to near (painter's order, so the nose hides the far
   cheek at large yaw) into a triangle-id buffer with ``cv2.fillConvexPoly``;
3. per pixel, barycentric coordinates interpolate texture coordinates and Gouraud shading
   (Lambert plus a Blinn-Phong highlight, light from a movable direction); the albedo atlas is
   sampled with one ``cv2.remap`` call at the mip level that matches the face's image scale;
4. the face is composited over the cluttered backdrop with an optics blur applied to the face
   and its coverage (anti-aliased edges); motion blur averages several poses over the exposure;
   occluders (a hand, a mug, a pen) pass in front; a camera with lens distortion (D, e.g.
   plumb_bob) gets the raw, distorted image, which its ``rectify_maps`` undo;
5. sensor gain, signal-dependent noise and 8-bit quantisation.

Projection uses the camera's P (eq. 2), so node ``i`` of a face is seen exactly where
``camera.project(R @ nodes[i] + t)`` says: the renderer's truth and the trackers' model agree.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy import sparse

from face_tracking_ros.errors import InputError
from face_tracking_ros.geometry.camera import PinholeCamera
from face_tracking_ros.geometry.rotation import rodrigues
from face_tracking_ros.synthetic.surface import HeadSurface, head_surface
from face_tracking_ros.synthetic.texture import TextureAtlas

_SHIFT = 4  # fixed-point bits of rasterised vertex coordinates
_MIN_DEPTH = 0.05  # m; faces closer than this are rejected
_NOISE_BANK_MARGIN = 64  # px of extra noise rows and columns for random crops
_REMAP_ROW = 1024  # points per row of a folded cv2.remap map


@dataclass(frozen=True)
class FacePose:
    """A face at one instant: true nodes and rigid pose (eq. 1).

    Attributes:
        nodes: (34, 3) nodes in the face frame, metres.
        omega: (3,) rotation vector of the face frame in the camera frame, radians.
        t: (3,) position of the face-frame origin in the camera frame, metres.
    """

    nodes: np.ndarray
    omega: np.ndarray
    t: np.ndarray

    def camera_nodes(self) -> np.ndarray:
        """Eq. 1: (34, 3) nodes in the camera frame, metres."""
        rotation, _ = rodrigues(self.omega)
        return self.nodes @ rotation.T + self.t


@dataclass(frozen=True)
class Lighting:
    """A directional light and the skin's reflectance.

    Attributes:
        direction: (3,) unit vector from the face towards the light, camera frame.
        ambient: ambient term (fraction of albedo).
        diffuse: Lambertian term.
        specular: Blinn-Phong highlight strength (fraction of full scale).
        shininess: Blinn-Phong exponent.
        colour: (3,) RGB light colour (mono images use its mean).
    """

    direction: np.ndarray = field(default_factory=lambda: np.array([-0.35, -0.45, -0.82]))
    ambient: float = 0.38
    diffuse: float = 0.72
    specular: float = 0.10
    shininess: float = 24.0
    colour: np.ndarray = field(default_factory=lambda: np.array([1.0, 0.97, 0.92]))


@dataclass(frozen=True)
class Sensor:
    """Camera optics and sensor.

    Attributes:
        blur_sigma: optics point-spread standard deviation, px.
        read_noise: signal-independent noise standard deviation, grey levels.
        shot_noise: signal-dependent noise variance per grey level (var = read^2 + shot I).
        gain: exposure gain applied before noise.
    """

    blur_sigma: float = 0.6
    read_noise: float = 1.5
    shot_noise: float = 0.04
    gain: float = 1.0


@dataclass(frozen=True)
class Occluder:
    """An object in front of the face, drawn in image coordinates.

    Attributes:
        centre: (x, y) px.
        axes: (a, b) semi-axes of its elliptical outline, px.
        angle: rotation of the outline, degrees.
        colour: (3,) RGB, grey levels (mono images use its luminance).
        texture_seed: seed of its surface texture.
    """

    centre: tuple[float, float]
    axes: tuple[float, float]
    angle: float
    colour: tuple[float, float, float]
    texture_seed: int = 0


@dataclass(frozen=True)
class _Layer:
    """A rendered face in an image region: premultiplied colour and coverage."""

    box: tuple[int, int, int, int]  # x0, y0, x1, y1 (exclusive)
    colour: np.ndarray  # (h, w) or (h, w, 3) float32, colour x coverage
    coverage: np.ndarray  # (h, w) float32 in [0, 1]


@dataclass(frozen=True)
class _Raster:
    """A face surface at one pose, projected and rasterised."""

    vertices: np.ndarray  # (M, 3) camera frame, m
    pixels: np.ndarray  # (M, 2) projections, px
    front: np.ndarray  # (F,) front-facing triangle indices in painter's order
    box: tuple[int, int, int, int]  # x0, y0, x1, y1 of the id buffer
    ids: np.ndarray  # (y1 - y0, x1 - x0) int32 index into front, -1 if empty


class FaceRenderer:
    """Renders one subject's textured face; one instance per subject and image encoding.

    Args:
        texture: the subject's albedo atlas (its encoding is the output encoding).
        sensor: optics and noise model.
        seed: seed of the sensor-noise bank.
        surface: the dense surface; defaults to :func:`head_surface`.
    """

    def __init__(
        self,
        texture: TextureAtlas,
        sensor: Sensor | None = None,
        seed: int = 0,
        surface: HeadSurface | None = None,
    ) -> None:
        """Precompute the vertex-triangle incidence used for vertex normals."""
        self.texture = texture
        self.sensor = Sensor() if sensor is None else sensor
        self.surface = head_surface() if surface is None else surface
        self._seed = seed
        self._noise_banks: dict[tuple[int, ...], np.ndarray] = {}
        self._distortion_maps: dict[tuple[float, ...], tuple[np.ndarray, np.ndarray]] = {}
        triangles = self.surface.triangles
        rows = triangles.ravel()
        cols = np.repeat(np.arange(len(triangles)), 3)
        self._incidence = sparse.csr_matrix(
            (np.ones(len(rows)), (rows, cols)), shape=(self.surface.num_vertices, len(triangles))
        )

    @property
    def encoding(self) -> str:
        """'mono8' or 'rgb8'."""
        return self.texture.encoding

    def render(
        self,
        camera: PinholeCamera,
        poses: Sequence[FacePose],
        background: np.ndarray,
        lighting: Lighting | None = None,
        occluders: Sequence[Occluder] = (),
        rng: np.random.Generator | None = None,
    ) -> np.ndarray:
        """Render one image.

        Args:
            camera: the camera (its P projects; eq. 2).
            poses: the face over the exposure; one pose for a sharp image, several (equally
                spaced in time) for motion blur.
            background: (H, W) or (H, W, 3) float32 backdrop as this camera sees it, grey levels.
            lighting: light and reflectance; default :class:`Lighting`.
            occluders: objects in front of the face.
            rng: per-frame randomness (noise crop); ``None`` renders without sensor noise.

        Returns:
            (H, W) uint8 (mono8) or (H, W, 3) uint8 (rgb8) image.

        Raises:
            InputError: for no poses, a background of the wrong shape, or a face behind the
                camera.
        """
        image, _ = self._render(camera, poses, background, lighting, occluders, rng)
        return image

    def render_with_visibility(
        self,
        camera: PinholeCamera,
        poses: Sequence[FacePose],
        background: np.ndarray,
        lighting: Lighting | None = None,
        occluders: Sequence[Occluder] = (),
        rng: np.random.Generator | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`render`, and :meth:`visible_nodes` of the middle pose from the same raster.

        Returns:
            ``(image, visible)``: the image and the (34,) bool visibility of the nodes.
        """
        image, rasters = self._render(camera, poses, background, lighting, occluders, rng)
        return image, self._visibility(camera, rasters[len(rasters) // 2])

    def _render(
        self,
        camera: PinholeCamera,
        poses: Sequence[FacePose],
        background: np.ndarray,
        lighting: Lighting | None,
        occluders: Sequence[Occluder],
        rng: np.random.Generator | None,
    ) -> tuple[np.ndarray, list[_Raster | None]]:
        """Render an image; also return the raster of each pose."""
        if not poses:
            raise InputError('render needs at least one face pose')
        expected = (camera.height, camera.width) + ((3,) if self.encoding == 'rgb8' else ())
        if background.shape != expected:
            msg = f'background has shape {background.shape}, expected {expected} for this camera'
            raise InputError(msg)
        lighting = Lighting() if lighting is None else lighting
        image = background.astype(np.float32, copy=True)
        rasters = [self._rasterise_pose(camera, pose) for pose in poses]
        self._composite(image, [self._face_layer(camera, r, lighting) for r in rasters])
        for occluder in occluders:
            self._draw_occluder(image, occluder)
        if camera.needs_rectification:
            image = cv2.remap(image, *self._raw_maps(camera), cv2.INTER_LINEAR)
        return self._expose(image, rng), rasters

    def _raw_maps(self, camera: PinholeCamera) -> tuple[np.ndarray, np.ndarray]:
        """cv2.remap maps taking the rendered (rectified, eq. 2) image to the camera's raw image.

        The inverse of :meth:`PinholeCamera.rectify_maps`: raw pixel q shows the rectified
        pixel ``camera.rectified_pixels(q)``. Computed once per camera.
        """
        key = tuple(np.concatenate([a.ravel() for a in (camera.k, camera.d, camera.r, camera.p)]))
        maps = self._distortion_maps.get((camera.width, camera.height, *key))
        if maps is None:
            columns, rows = np.meshgrid(np.arange(camera.width), np.arange(camera.height))
            raw = np.stack([columns, rows], axis=-1).reshape(-1, 2).astype(np.float64)
            rectified = camera.rectified_pixels(raw)
            rectified = rectified.reshape(camera.height, camera.width, 2).astype(np.float32)
            maps = (rectified[..., 0], rectified[..., 1])
            self._distortion_maps[(camera.width, camera.height, *key)] = maps
        return maps

    def visible_nodes(
        self,
        camera: PinholeCamera,
        pose: FacePose,
        tolerance: float = 0.001,
        min_cosine: float = 0.2,
    ) -> np.ndarray:
        """Which of the 34 nodes the camera sees clearly (not hidden, not grazing, in the image).

        A node is visible if the four pixels around its projection (the support of a bilinear
        read there) all show the node's own surface: a triangle that has the node as a vertex, or
        a surface point within ``tolerance`` (m) of the node's depth. It must also face the
        camera (cosine between its normal and the line of sight >= ``min_cosine``). Nodes hidden
        by the nose or cheek, on the face's silhouette (the far face edge at large yaw) or off
        the image do not count.

        Returns:
            (34,) bool.
        """
        return self._visibility(camera, self._rasterise_pose(camera, pose), tolerance, min_cosine)

    def _visibility(
        self,
        camera: PinholeCamera,
        raster: _Raster | None,
        tolerance: float = 0.001,
        min_cosine: float = 0.2,
    ) -> np.ndarray:
        """The (34,) visibility of :meth:`visible_nodes` from a pose's raster."""
        nodes = self.surface.node_vertices
        if raster is None:
            return np.zeros(len(nodes), bool)
        x0, y0, x1, y1 = raster.box
        corner = np.floor(raster.pixels[nodes]).astype(np.int64)
        offsets = np.array([[0, 0], [1, 0], [0, 1], [1, 1]])
        support = corner[:, None, :] + offsets[None]  # (34, 4, 2) pixel (x, y)
        column, row = support[..., 0] - x0, support[..., 1] - y0
        inside = (column >= 0) & (column < x1 - x0) & (row >= 0) & (row < y1 - y0)
        slot = np.full(column.shape, -1)
        slot[inside] = raster.ids[row[inside], column[inside]]
        covered = slot >= 0
        triangles = self.surface.triangles[raster.front]
        own = np.zeros(column.shape, bool)
        own[covered] = np.any(
            triangles[slot[covered]] == np.repeat(nodes, 4).reshape(-1, 4)[covered][:, None],
            axis=1,
        )
        maps = _affine_attribute_maps(raster.pixels, triangles, raster.vertices[:, 2:3])
        drawn = np.full(column.shape, -np.inf)
        chosen = maps[slot[covered], 0]
        drawn[covered] = (
            chosen[:, 0] * support[..., 0][covered]
            + chosen[:, 1] * support[..., 1][covered]
            + chosen[:, 2]
        )
        near = np.abs(drawn - raster.vertices[nodes, 2][:, None]) <= tolerance
        normals = self._vertex_normals(raster.vertices)[nodes]
        sight = raster.vertices[nodes] - _optical_centre(camera)
        sight /= np.linalg.norm(sight, axis=1, keepdims=True)
        facing = -np.einsum('nd,nd->n', normals, sight) >= min_cosine
        return np.all(covered & (own | near), axis=1) & facing

    def _rasterise_pose(self, camera: PinholeCamera, pose: FacePose) -> _Raster | None:
        """Move the surface to a pose (eq. 1), project it (eq. 2) and build its id buffer.

        Returns:
            the raster, or None if no front-facing triangle falls in the image.

        Raises:
            InputError: if part of the face is behind or too close to the camera.
        """
        rotation, _ = rodrigues(np.asarray(pose.omega, dtype=float))
        vertices = self.surface.vertices(np.asarray(pose.nodes, dtype=float)) @ rotation.T + pose.t
        if np.min(vertices[:, 2]) < _MIN_DEPTH:
            nearest = vertices[:, 2].min()
            msg = f'face is behind or too close to the camera (min depth {nearest:.3f} m)'
            raise InputError(msg)
        pixels = camera.project(vertices)
        triangles = self.surface.triangles
        a, b, c = (pixels[triangles[:, k]] for k in range(3))
        area = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (
            c[:, 0] - a[:, 0]
        )
        front = np.flatnonzero(area > 1e-3)
        if front.size == 0:
            return None
        # Painter's order: far triangles first, so near ones overwrite them.
        depth = vertices[:, 2][triangles[front]].mean(axis=1)
        front = front[np.argsort(-depth, kind='stable')]
        box = _bounding_box(pixels[triangles[front]].reshape(-1, 2), camera)
        x0, y0, x1, y1 = box
        if x1 <= x0 or y1 <= y0:
            return None
        ids = _rasterise(pixels - [x0, y0], triangles[front], (y1 - y0, x1 - x0))
        return _Raster(vertices=vertices, pixels=pixels, front=front, box=box, ids=ids)

    def _face_layer(
        self, camera: PinholeCamera, raster: _Raster | None, lighting: Lighting
    ) -> _Layer:
        """Shade and texture the face of one pose's raster."""
        if raster is None:
            return _Layer((0, 0, 0, 0), np.zeros((0, 0), np.float32), np.zeros((0, 0), np.float32))
        vertices, pixels, ids = raster.vertices, raster.pixels, raster.ids
        x0, y0 = raster.box[:2]
        rows, cols = np.nonzero(ids >= 0)
        # Per triangle, an affine map from pixel (x, y, 1) to its attributes: atlas x, atlas y,
        # shading factor and highlight (barycentric interpolation written once per triangle).
        level = self.texture.level_for(1000.0 * float(np.median(vertices[:, 2])) / camera.focal)
        diffuse, highlight = self._shading(vertices - _optical_centre(camera), lighting)
        attributes = np.column_stack(
            [self.texture.pixel_coordinates(self.surface.uv, level), diffuse, 255.0 * highlight]
        )
        triangles = self.surface.triangles[raster.front]
        maps = _affine_attribute_maps(pixels, triangles, attributes)[ids[rows, cols]]
        x = (cols + x0).astype(np.float32)[:, None]
        y = (rows + y0).astype(np.float32)[:, None]
        values = maps[:, :, 0] * x + maps[:, :, 1] * y + maps[:, :, 2]
        albedo = _sample(self.texture.levels[level], values[:, :2])
        shade, gloss = values[:, 2], values[:, 3]
        light = np.asarray(lighting.colour, dtype=np.float32)
        colour = np.zeros(ids.shape + albedo.shape[1:], np.float32)
        if albedo.ndim == 2:  # rgb8: (P, 3) samples
            colour[rows, cols] = (albedo * shade[:, None] + gloss[:, None]) * light
        else:
            colour[rows, cols] = (albedo * shade + gloss) * light.mean()
        coverage = (ids >= 0).astype(np.float32)
        return _Layer(raster.box, colour, coverage)

    def _vertex_normals(self, vertices: np.ndarray) -> np.ndarray:
        """(M, 3) unit outward vertex normals (area-weighted sums of triangle normals)."""
        triangles = self.surface.triangles
        a, b, c = (vertices[triangles[:, k]] for k in range(3))
        # Triangles are counter-clockwise in uv with y down and z into the head, so this cross
        # product points into the head: negate it for the outward normal.
        normals = self._incidence @ -np.cross(b - a, c - a)
        return normals / (np.linalg.norm(normals, axis=1, keepdims=True) + 1e-12)

    def _shading(self, vertices: np.ndarray, lighting: Lighting) -> tuple[np.ndarray, np.ndarray]:
        """Per-vertex Lambert (ambient + diffuse) factor and Blinn-Phong highlight, (M,) each.

        Args:
            vertices: (M, 3) vertices relative to the viewing camera's optical centre, m.
            lighting: the light.
        """
        normals = self._vertex_normals(vertices)
        light = np.asarray(lighting.direction, dtype=float)
        light = light / np.linalg.norm(light)
        view = -vertices / np.linalg.norm(vertices, axis=1, keepdims=True)
        half = light + view
        half /= np.linalg.norm(half, axis=1, keepdims=True) + 1e-12
        lambert = np.clip(normals @ light, 0.0, None)
        diffuse = lighting.ambient + lighting.diffuse * lambert
        highlight = lighting.specular * np.clip(np.einsum('md,md->m', normals, half), 0, None) ** (
            lighting.shininess
        )
        return diffuse.astype(np.float32), (highlight * (lambert > 0)).astype(np.float32)

    def _composite(self, image: np.ndarray, layers: list[_Layer]) -> None:
        """Average the layers (motion blur), blur by the optics and blend over the image."""
        boxes = np.array([layer.box for layer in layers if layer.coverage.size])
        if boxes.size == 0:
            return
        pad = int(np.ceil(3 * self.sensor.blur_sigma)) + 1
        height, width = image.shape[:2]
        x0, y0 = max(boxes[:, 0].min() - pad, 0), max(boxes[:, 1].min() - pad, 0)
        x1, y1 = min(boxes[:, 2].max() + pad, width), min(boxes[:, 3].max() + pad, height)
        colour = np.zeros((y1 - y0, x1 - x0) + image.shape[2:], np.float32)
        coverage = np.zeros((y1 - y0, x1 - x0), np.float32)
        for layer in layers:
            if not layer.coverage.size:
                continue
            lx0, ly0, lx1, ly1 = layer.box
            region = np.s_[ly0 - y0 : ly1 - y0, lx0 - x0 : lx1 - x0]
            colour[region] += layer.colour
            coverage[region] += layer.coverage
        colour /= len(layers)
        coverage /= len(layers)
        if self.sensor.blur_sigma > 0:
            colour = cv2.GaussianBlur(colour, (0, 0), self.sensor.blur_sigma)
            coverage = cv2.GaussianBlur(coverage, (0, 0), self.sensor.blur_sigma)
        target = image[y0:y1, x0:x1]
        weight = coverage[..., None] if image.ndim == 3 else coverage
        target *= 1.0 - weight
        target += colour

    def _draw_occluder(self, image: np.ndarray, occluder: Occluder) -> None:
        """Blend a textured, anti-aliased ellipse over the image."""
        height, width = image.shape[:2]
        reach = int(max(occluder.axes)) + 2
        cx, cy = occluder.centre
        x0, y0 = max(int(cx) - reach, 0), max(int(cy) - reach, 0)
        x1, y1 = min(int(cx) + reach + 1, width), min(int(cy) + reach + 1, height)
        if x1 <= x0 or y1 <= y0:
            return
        mask = np.zeros((y1 - y0, x1 - x0), np.uint8)
        centre = (round((cx - x0) * 2**_SHIFT), round((cy - y0) * 2**_SHIFT))
        axes = tuple(round(a * 2**_SHIFT) for a in occluder.axes)
        cv2.ellipse(mask, centre, axes, occluder.angle, 0, 360, 255, -1, cv2.LINE_AA, _SHIFT)
        alpha = mask.astype(np.float32) / 255.0
        rng = np.random.default_rng(occluder.texture_seed)
        grain = cv2.resize(
            rng.normal(1.0, 0.12, (mask.shape[0] // 6 + 2, mask.shape[1] // 6 + 2)),
            mask.shape[::-1], interpolation=cv2.INTER_CUBIC,
        ).astype(np.float32)  # fmt: skip
        colour = np.asarray(occluder.colour, dtype=np.float32)
        if image.ndim == 2:
            colour = np.float32(colour @ np.array([0.299, 0.587, 0.114], np.float32))
            target, weight, paint = image[y0:y1, x0:x1], alpha, grain * colour
        else:
            target, weight, paint = (
                image[y0:y1, x0:x1],
                alpha[..., None],
                grain[..., None] * colour,
            )
        target += weight * (paint - target)

    def _expose(self, image: np.ndarray, rng: np.random.Generator | None) -> np.ndarray:
        """Gain, signal-dependent noise and 8-bit quantisation."""
        sensor = self.sensor
        if sensor.gain != 1.0:
            image *= sensor.gain
        if rng is not None:
            bank = self._noise_bank(image.shape)
            oy, ox = (int(v) for v in rng.integers(0, _NOISE_BANK_MARGIN, 2))
            noise = bank[oy : oy + image.shape[0], ox : ox + image.shape[1]]
            sigma = np.sqrt(sensor.read_noise**2 + sensor.shot_noise * np.clip(image, 0, None))
            image += noise * sigma
        np.clip(image + 0.5, 0.0, 255.0, out=image)
        return image.astype(np.uint8)

    def _noise_bank(self, shape: tuple[int, ...]) -> np.ndarray:
        """A standard-normal float32 noise image larger than ``shape``; random crops vary it."""
        bank = self._noise_banks.get(shape)
        if bank is None:
            rng = np.random.default_rng(self._seed)
            size = (shape[0] + _NOISE_BANK_MARGIN, shape[1] + _NOISE_BANK_MARGIN, *shape[2:])
            bank = rng.standard_normal(size, dtype=np.float32)
            self._noise_banks[shape] = bank
        return bank


def _optical_centre(camera: PinholeCamera) -> np.ndarray:
    """(3,) optical centre (m) of a camera in the frame of its P; (B, 0, 0) for a right one."""
    return -np.linalg.solve(camera.p[:, :3], camera.p[:, 3])


def _sample(atlas: np.ndarray, coords: np.ndarray) -> np.ndarray:
    """Bilinear samples (P,) or (P, 3) float32 of an atlas at (P, 2) pixel coordinates.

    cv2.remap maps must be under 32767 wide, so the points are folded into rows.
    """
    count = len(coords)
    if count == 0:  # a face covering no pixel centre (cv2.remap refuses empty maps)
        return np.zeros((0, *atlas.shape[2:]), np.float32)
    padded = np.zeros((-(-count // _REMAP_ROW) * _REMAP_ROW, 2), np.float32)
    padded[:count] = coords
    folded = padded.reshape(-1, _REMAP_ROW, 2)
    samples = cv2.remap(
        atlas, folded[..., 0], folded[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE
    )
    return samples.reshape(-1, *atlas.shape[2:])[:count].astype(np.float32)


def _bounding_box(points: np.ndarray, camera: PinholeCamera) -> tuple[int, int, int, int]:
    """Integer (x0, y0, x1, y1) box of points, clipped to the image."""
    x0 = int(np.clip(np.floor(points[:, 0].min()) - 1, 0, camera.width))
    y0 = int(np.clip(np.floor(points[:, 1].min()) - 1, 0, camera.height))
    x1 = int(np.clip(np.ceil(points[:, 0].max()) + 2, 0, camera.width))
    y1 = int(np.clip(np.ceil(points[:, 1].max()) + 2, 0, camera.height))
    return x0, y0, x1, y1


def _rasterise(pixels: np.ndarray, triangles: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Triangle-id buffer: for each pixel centre, the last of ``triangles`` that covers it.

    With triangles in painter's order (far first) this is a z-buffer at triangle granularity.
    Vectorised scan conversion: each triangle is cut into one span per pixel row it crosses (the
    row's intersections with its edges), spans are expanded to pixels, and ``np.maximum.at``
    keeps the highest (nearest) triangle at each pixel. Pixel centres on a shared edge belong to
    both triangles, so meshes render without cracks.

    Args:
        pixels: (M, 2) vertex pixel coordinates relative to the buffer's corner.
        triangles: (F, 3) vertex indices.
        shape: (rows, cols) of the buffer.

    Returns:
        (rows, cols) int32 index into ``triangles``, -1 where no triangle covers the pixel.
    """
    rows, cols = shape
    corners = pixels[triangles]  # (F, 3, 2)
    y_low = np.maximum(np.ceil(corners[:, :, 1].min(axis=1)), 0).astype(np.int64)
    y_high = np.minimum(np.floor(corners[:, :, 1].max(axis=1)), rows - 1).astype(np.int64)
    owner, y = _expand(y_low, np.maximum(y_high - y_low + 1, 0))
    start = corners[owner]  # (S, 3, 2): each span's triangle
    end = np.roll(start, -1, axis=1)
    rise = end[..., 1] - start[..., 1]
    flat = np.abs(rise) < 1e-12
    t = (y[:, None] - start[..., 1]) / np.where(flat, 1.0, rise)
    crossing = ~flat & (t >= -1e-9) & (t <= 1.0 + 1e-9)
    x = start[..., 0] + t * (end[..., 0] - start[..., 0])
    x_left = np.ceil(np.where(crossing, x, np.inf).min(axis=1))
    x_right = np.floor(np.where(crossing, x, -np.inf).max(axis=1))
    x_left = np.maximum(x_left, 0).astype(np.int64)
    x_right = np.minimum(x_right, cols - 1).astype(np.int64)
    span, x = _expand(x_left, np.maximum(x_right - x_left + 1, 0))
    ids = np.full(rows * cols, -1, np.int32)
    np.maximum.at(ids, y[span] * cols + x, owner[span].astype(np.int32))
    return ids.reshape(rows, cols)


def _expand(first: np.ndarray, counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Expand ranges ``first[i] .. first[i] + counts[i] - 1`` into (range index, value) pairs."""
    index = np.repeat(np.arange(len(counts)), counts)
    offsets = np.arange(int(counts.sum())) - np.repeat(np.cumsum(counts) - counts, counts)
    return index, first[index] + offsets


def _barycentric_maps(pixels: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(F, 3, 3) per-triangle affine maps from pixel (x, y, 1) to barycentric coordinates.

    Row k of ``maps[f]`` gives the weight of vertex k of triangle f; degenerate triangles get
    zeros (no pixel is inside them).
    """
    x, y = (pixels[:, k][triangles] for k in range(2))  # (F, 3) each
    determinant = (y[:, 1] - y[:, 2]) * (x[:, 0] - x[:, 2]) + (x[:, 2] - x[:, 1]) * (
        y[:, 0] - y[:, 2]
    )
    valid = np.abs(determinant) > 1e-9
    inverse = np.where(valid, 1.0 / np.where(valid, determinant, 1.0), 0.0)
    maps = np.zeros((len(triangles), 3, 3))
    for k, (i, j) in enumerate(((1, 2), (2, 0))):
        dy, dx = y[:, i] - y[:, j], x[:, j] - x[:, i]
        maps[:, k] = np.column_stack([dy, dx, -dy * x[:, 2] - dx * y[:, 2]]) * inverse[:, None]
    maps[:, 2] = -maps[:, 0] - maps[:, 1] + np.outer(valid, [0.0, 0.0, 1.0])
    return maps


def _affine_attribute_maps(
    pixels: np.ndarray, triangles: np.ndarray, attributes: np.ndarray
) -> np.ndarray:
    """(F, D, 3) float32 per-triangle affine maps from pixel (x, y, 1) to vertex attributes.

    Inside triangle f, ``maps[f] @ (x, y, 1)`` is the barycentric interpolation of the (M, D)
    vertex ``attributes`` at the (M, 2) vertex ``pixels``.
    """
    barycentric = _barycentric_maps(pixels, triangles)
    return np.einsum('fkd,fkc->fdc', attributes[triangles], barycentric).astype(np.float32)
