"""Surface textures (albedo atlases) of the synthetic faces: procedural skin, a photo, or markers.

A texture is an image over the surface's uv coordinates (mm, see
:mod:`face_tracking_ros.synthetic.surface`). Because each mesh node's uv is its reference (x, y),
features drawn at those uv (eye corners, pupils, mouth corners, nostril wings, brow ends) are the
nodes: wherever the renderer puts a node, its feature is there too.

The procedural skin has detail at every scale a tracker meets on a real face: low-frequency
blotches and redness, mid-frequency mottling, pores and moles, stubble on some subjects, hair
with strands, eyes with lids, lashes, irises and catchlights, brows made of hair strokes,
nostrils, lips and folds. A subject's colours come from its ``appearance_seed``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
import json
from pathlib import Path

import cv2
import numpy as np
from scipy.interpolate import PchipInterpolator, RBFInterpolator

from face_tracking_ros.errors import ConfigError
from face_tracking_ros.model.topology import mesh_topology
from face_tracking_ros.synthetic.surface import outline_radius
from face_tracking_ros.tracking.initialisation import is_point, unique_json_keys
from face_tracking_ros.wording import listed

ENCODINGS = ('mono8', 'rgb8')

# Atlas domain in uv (mm): the head (u within +-96) and the neck strip (u about 130 to 270).
ATLAS_ORIGIN = (-96.0, -128.0)
ATLAS_EXTENT = (372.0, 372.0)
ATLAS_MM_PER_PX = 0.25
ATLAS_LEVELS = 4
MIN_PHOTO_NODES = 10
_WARP_STEP = 8  # coarse-grid step of the photo warp, atlas pixels (divides the atlas size)
_WARP_CENTRE = (_WARP_STEP - 1) / 2  # fine pixel of coarse sample 0 under cv2.resize

# cv2 draws in fixed point with 4 fractional bits: features sit to 1/16 atlas pixel.
_SHIFT = 4


@dataclass(frozen=True)
class TextureAtlas:
    """An albedo image over uv with its mip levels.

    Attributes:
        levels: mip pyramid, level 0 first; each (H, W) uint8 (mono8) or (H, W, 3) uint8 (rgb8).
        origin: uv (mm) of level-0 pixel (0, 0).
        mm_per_px: level-0 pixel size, mm.
    """

    levels: tuple[np.ndarray, ...]
    origin: tuple[float, float] = ATLAS_ORIGIN
    mm_per_px: float = ATLAS_MM_PER_PX

    @property
    def encoding(self) -> str:
        """'mono8' or 'rgb8'."""
        return 'rgb8' if self.levels[0].ndim == 3 else 'mono8'

    def level_for(self, image_mm_per_px: float) -> int:
        """The coarsest mip level whose pixels are no larger than an image pixel on the face."""
        ratio = max(image_mm_per_px / self.mm_per_px, 1.0)
        return int(min(np.floor(np.log2(ratio)), len(self.levels) - 1))

    def pixel_coordinates(self, uv: np.ndarray, level: int) -> np.ndarray:
        """(K, 2) float32 atlas pixel coordinates at ``level`` of (K, 2) uv in mm.

        cv2.pyrDown keeps level-0 pixel 2^L i at level-L pixel i, so coordinates simply scale.
        """
        scale = self.mm_per_px * 2**level
        return ((uv - np.asarray(self.origin)) / scale).astype(np.float32)


@dataclass(frozen=True)
class Appearance:
    """Colours of one subject, RGB albedo in [0, 1].

    Attributes:
        skin: (3,) skin tone.
        hair: (3,) hair and brow colour.
        iris: (3,) iris colour.
        lips: (3,) lip colour.
        stubble: beard stubble density, 0 (none) to 1.
    """

    skin: np.ndarray
    hair: np.ndarray
    iris: np.ndarray
    lips: np.ndarray
    stubble: float

    @classmethod
    def from_seed(cls, seed: int) -> Appearance:
        """A random appearance: skin from light to dark, natural hair and iris colours."""
        rng = np.random.default_rng(seed)
        tone = rng.uniform(0.0, 1.0)
        light, dark = np.array([0.86, 0.68, 0.58]), np.array([0.36, 0.23, 0.16])
        skin = np.clip((1.0 - tone) * light + tone * dark + rng.normal(0.0, 0.02, 3), 0.1, 0.95)
        hairs = np.array(
            [[0.08, 0.06, 0.05], [0.22, 0.14, 0.08], [0.42, 0.3, 0.17], [0.55, 0.5, 0.45]]
        )
        irises = np.array([[0.25, 0.14, 0.07], [0.2, 0.3, 0.45], [0.3, 0.35, 0.2]])
        bearded = rng.uniform() < 0.4
        return cls(
            skin=skin,
            hair=hairs[rng.integers(len(hairs))],
            iris=irises[rng.integers(len(irises))],
            lips=np.clip(skin * np.array([0.92, 0.6, 0.62]), 0.05, 0.9),
            stubble=float(rng.uniform(0.3, 1.0)) if bearded else 0.0,
        )


def procedural_texture(appearance_seed: int, encoding: str = 'mono8') -> TextureAtlas:
    """The procedural skin, hair and facial features of one subject.

    Args:
        appearance_seed: seed of the subject's colours and skin detail.
        encoding: 'mono8' or 'rgb8'.

    Raises:
        ConfigError: for an unknown encoding.
    """
    _check_encoding(encoding)
    rng = np.random.default_rng(appearance_seed)
    appearance = Appearance.from_seed(appearance_seed)
    canvas = _Canvas.empty()
    canvas.skin(rng, appearance)
    canvas.stubble(rng, appearance)
    canvas.hair(rng, appearance)
    canvas.eyes(rng, appearance)
    canvas.brows(rng, appearance)
    canvas.nose_and_folds(appearance)
    canvas.mouth(rng, appearance)
    return atlas_from_rgb(canvas.rgb, encoding)


def photo_texture(
    photo: np.ndarray, node_pixels: Mapping[str, tuple[float, float]], encoding: str = 'mono8'
) -> TextureAtlas:
    """Map a face photo onto the surface through its node positions.

    A thin-plate spline from the nodes' uv to their photo pixels warps the photo into the atlas,
    so each named node's photo feature lands on that node.

    Args:
        photo: (H, W) uint8 grey or (H, W, 3) uint8 RGB photo of a roughly frontal face.
        node_pixels: photo pixel (x, y) of at least 10 named mesh nodes, including both eyes.
        encoding: 'mono8' or 'rgb8'.

    Raises:
        ConfigError: for unknown node names, too few nodes, or a photo that is not uint8.
    """
    _check_encoding(encoding)
    names = mesh_topology(34).node_names
    unknown = sorted(set(node_pixels) - set(names))
    if unknown:
        known = ', '.join(names)
        msg = f'photo node positions name unknown {listed("node", unknown)}; known: {known}'
        raise ConfigError(msg)
    if len(node_pixels) < MIN_PHOTO_NODES or not {'right_eye', 'left_eye'} <= set(node_pixels):
        msg = (
            f'photo node positions need at least {MIN_PHOTO_NODES} nodes including right_eye and '
            f'left_eye; got {sorted(node_pixels)}'
        )
        raise ConfigError(msg)
    if photo.dtype != np.uint8 or photo.ndim not in (2, 3):
        msg = f'photo must be a uint8 grey or RGB image, got {photo.dtype} {photo.shape}'
        raise ConfigError(msg)
    reference = _reference_uv()
    uv = np.array([reference[name] for name in node_pixels])
    pixels = np.array([node_pixels[name] for name in node_pixels], dtype=float)
    warp = RBFInterpolator(uv, pixels, kernel='thin_plate_spline', smoothing=0.0)
    # The warp is smooth: evaluate it on a grid 8 times coarser and upsample. cv2.resize puts
    # coarse sample k at fine pixel 8 k + 3.5, which is where the coarse grid is evaluated.
    rows, cols = atlas_uv()[0].shape
    u = ATLAS_ORIGIN[0] + ATLAS_MM_PER_PX * (
        _WARP_STEP * np.arange(cols // _WARP_STEP) + _WARP_CENTRE
    )
    v = ATLAS_ORIGIN[1] + ATLAS_MM_PER_PX * (
        _WARP_STEP * np.arange(rows // _WARP_STEP) + _WARP_CENTRE
    )
    coarse_u, coarse_v = np.meshgrid(u, v)
    coarse = warp(np.stack([coarse_u, coarse_v], axis=-1).reshape(-1, 2))
    coarse = coarse.reshape(*coarse_u.shape, 2).astype(np.float32)
    maps = cv2.resize(coarse, (cols, rows), interpolation=cv2.INTER_LINEAR)
    rgb_photo = photo if photo.ndim == 3 else cv2.cvtColor(photo, cv2.COLOR_GRAY2RGB)
    atlas = cv2.remap(
        rgb_photo, maps[..., 0], maps[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT
    )
    return atlas_from_rgb(atlas.astype(np.float32) / 255.0, encoding)


def require_file(path: Path, what: str) -> None:
    """Refuse a path to ``what`` (e.g. 'texture photo') that is not a file.

    Raises:
        ConfigError: saying whether it is a directory or does not exist.
    """
    if path.is_dir():
        msg = f'{what} {path} is a directory, not a file'
        raise ConfigError(msg)
    if not path.is_file():
        msg = f'{what} file not found: {path}'
        raise ConfigError(msg)


def load_photo_texture(
    photo_path: str | Path, nodes_path: str | Path, encoding: str = 'mono8'
) -> TextureAtlas:
    """Read a photo and a JSON ``{node name: [x, y]}`` of its pixels, then :func:`photo_texture`.

    Raises:
        ConfigError: if a file is missing or unreadable, or the JSON is not a name -> [x, y] map.
    """
    photo_path, nodes_path = Path(photo_path), Path(nodes_path)
    require_file(photo_path, 'texture photo')
    require_file(nodes_path, 'texture node positions')
    photo = cv2.imread(str(photo_path), cv2.IMREAD_COLOR)
    if photo is None:
        msg = f'cannot read texture photo {photo_path} as an image'
        raise ConfigError(msg)
    node_pixels = _node_pixels(nodes_path)
    height, width = photo.shape[:2]
    outside = [
        name
        for name, (x, y) in node_pixels.items()
        if not (0.0 <= x <= width - 1 and 0.0 <= y <= height - 1)  # NaN is not inside either
    ]
    if outside:
        msg = (
            f'{nodes_path}: {listed("node", outside)} not inside the {width}x{height} '
            f'photo {photo_path} (or not finite)'
        )
        raise ConfigError(msg)
    return photo_texture(cv2.cvtColor(photo, cv2.COLOR_BGR2RGB), node_pixels, encoding)


def _node_pixels(path: Path) -> dict[str, tuple[float, float]]:
    """The ``{node name: [x, y]}`` of a JSON file, each node once, two numbers a node.

    Raises:
        ConfigError: naming the file and the problem (not JSON, not an object, a node given
            twice, a position that is not two numbers).
    """
    problem = f'{path} must be a JSON object {{node name: [x, y]}}'
    try:
        raw = json.loads(path.read_text(), object_pairs_hook=unique_json_keys)
    except ValueError as error:  # json's, a key given twice, an integer of > 4300 digits
        msg = f'{problem}: {error}'
        raise ConfigError(msg) from None
    if not isinstance(raw, dict):
        msg = f'{problem}: got a JSON {type(raw).__name__}'
        raise ConfigError(msg)
    for name, xy in raw.items():
        if not is_point(xy):
            msg = f'{problem}: node {name!r} must be [x, y] in pixels, got {xy!r}'
            raise ConfigError(msg)
    return {str(name): (float(x), float(y)) for name, (x, y) in raw.items()}


def _check_encoding(encoding: str) -> None:
    """Raise ConfigError for an unknown image encoding."""
    if encoding not in ENCODINGS:
        msg = f'unknown image encoding {encoding!r}; choose one of {ENCODINGS}'
        raise ConfigError(msg)


def atlas_from_rgb(rgb: np.ndarray, encoding: str) -> TextureAtlas:
    """Quantise a float RGB albedo in [0, 1] over :func:`atlas_uv` to a uint8 atlas with mips."""
    image = np.clip(rgb * 255.0 + 0.5, 0, 255).astype(np.uint8)
    if encoding == 'mono8':
        image = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    levels = [image]
    for _ in range(ATLAS_LEVELS - 1):
        levels.append(cv2.pyrDown(levels[-1]))
    return TextureAtlas(levels=tuple(levels))


def atlas_uv() -> tuple[np.ndarray, np.ndarray]:
    """U and v (mm) of every level-0 atlas pixel, each (rows, cols) float32."""
    cols, rows = (int(extent / ATLAS_MM_PER_PX) for extent in ATLAS_EXTENT)
    u = ATLAS_ORIGIN[0] + ATLAS_MM_PER_PX * np.arange(cols, dtype=np.float32)
    v = ATLAS_ORIGIN[1] + ATLAS_MM_PER_PX * np.arange(rows, dtype=np.float32)
    return np.meshgrid(u, v)


def _reference_uv() -> dict[str, np.ndarray]:
    """Uv (mm) of every node: its reference (x, y), where its texture feature is drawn."""
    topology = mesh_topology(34)
    return dict(zip(topology.node_names, 1000.0 * topology.reference_shape[:, :2], strict=True))


def _px(uv: np.ndarray | list[tuple[float, float]]) -> np.ndarray:
    """int32 fixed-point atlas pixel coordinates of uv points (mm), for cv2 drawing."""
    points = (np.asarray(uv, dtype=float) - ATLAS_ORIGIN) / ATLAS_MM_PER_PX
    return np.round(points * 2**_SHIFT).astype(np.int32)


def _radius(length_mm: float) -> int:
    """A radius in mm in fixed-point atlas pixels, for cv2 drawing."""
    return round(length_mm / ATLAS_MM_PER_PX * 2**_SHIFT)


def _curve(xs: list[float], ys: list[float], side: float, count: int = 48) -> np.ndarray:
    """(count, 2) uv curve through points given for the subject's left (x > 0), mirrored by side.

    Passes exactly through every given point (PCHIP); ``side`` is +1 (left) or -1 (right).
    """
    x = np.linspace(xs[0], xs[-1], count)
    return np.stack([side * x, PchipInterpolator(xs, ys)(x)], axis=1)


@dataclass
class _Canvas:
    """The float RGB albedo being painted, with the uv of its pixels."""

    rgb: np.ndarray
    u: np.ndarray
    v: np.ndarray

    @classmethod
    def empty(cls) -> _Canvas:
        """A black canvas over the atlas domain."""
        u, v = atlas_uv()
        return cls(rgb=np.zeros((*u.shape, 3), np.float32), u=u, v=v)

    @property
    def shape(self) -> tuple[int, int]:
        """(rows, cols)."""
        return self.u.shape

    def blend(self, mask: np.ndarray, colour: np.ndarray | tuple[float, ...]) -> None:
        """Rgb = (1 - mask) rgb + mask colour; colour is (3,) or per pixel (rows, cols, 3).

        Only the bounding box of the mask's support is touched (features are small).
        """
        x, y, w, h = cv2.boundingRect((mask > 1e-3).astype(np.uint8))
        box = np.s_[y : y + h, x : x + w]
        colour = np.asarray(colour, dtype=np.float32)
        target = colour[box] if colour.ndim == 3 else colour
        self.rgb[box] += mask[box][..., None] * (target - self.rgb[box])

    def bump(self, x: float, y: float, sx: float, sy: float) -> np.ndarray:
        """Gaussian bump (rows, cols) centred at uv (x, y) with standard deviations in mm."""
        return np.exp(-0.5 * (((self.u - x) / sx) ** 2 + ((self.v - y) / sy) ** 2))

    def noise(self, rng: np.random.Generator, scale_mm: float) -> np.ndarray:
        """Zero-mean, unit-std smooth noise with features of about ``scale_mm``, float32."""
        step = max(scale_mm / ATLAS_MM_PER_PX, 1.0)
        rows, cols = self.shape
        small = rng.standard_normal((int(rows / step) + 3, int(cols / step) + 3))
        noise = cv2.resize(small.astype(np.float32), (cols, rows), interpolation=cv2.INTER_CUBIC)
        return (noise - noise.mean()) / (noise.std() + 1e-6)

    def speckle(self, rng: np.random.Generator, density: float, blur_mm: float) -> np.ndarray:
        """Sparse soft dots (pores, stubble): a mask in [0, 1]."""
        dots = (rng.random(self.shape) < density).astype(np.float32)
        sigma = blur_mm / ATLAS_MM_PER_PX
        return np.clip(cv2.GaussianBlur(dots, (0, 0), sigma) * 2.0 * np.pi * sigma**2, 0.0, 1.0)

    def draw(self, paint: Callable[[np.ndarray], object], blur_mm: float = 0.0) -> np.ndarray:
        """A mask in [0, 1] painted anti-aliased by ``paint(layer)`` on a uint8 layer."""
        layer = np.zeros(self.shape, np.uint8)
        paint(layer)
        mask = layer.astype(np.float32) / 255.0
        if blur_mm > 0.0:
            mask = cv2.GaussianBlur(mask, (0, 0), blur_mm / ATLAS_MM_PER_PX)
        return mask

    def polygon(self, outline: np.ndarray, blur_mm: float = 0.0) -> np.ndarray:
        """Mask of the polygon with the (K, 2) uv outline."""
        points = _px(outline)
        return self.draw(
            lambda layer: cv2.fillPoly(layer, [points], 255, cv2.LINE_AA, _SHIFT), blur_mm
        )

    def polyline(self, curve: np.ndarray, width_mm: float, blur_mm: float = 0.0) -> np.ndarray:
        """Mask of a (K, 2) uv polyline of the given width."""
        points = _px(curve)
        thickness = max(1, round(width_mm / ATLAS_MM_PER_PX))
        return self.draw(
            lambda layer: cv2.polylines(
                layer, [points], False, 255, thickness, cv2.LINE_AA, _SHIFT
            ),
            blur_mm,
        )

    def disc(
        self, centre: tuple[float, float], radius_mm: float, blur_mm: float = 0.0
    ) -> np.ndarray:
        """Mask of a disc at a uv centre."""
        point = _px([centre])[0]
        radius = _radius(radius_mm)
        return self.draw(
            lambda layer: cv2.circle(layer, point, radius, 255, -1, cv2.LINE_AA, _SHIFT), blur_mm
        )

    def skin(self, rng: np.random.Generator, appearance: Appearance) -> None:
        """Skin tone with blotches, redness, mottling, pores and moles."""
        self.rgb[:] = appearance.skin
        brightness = (
            1.0
            + 0.035 * self.noise(rng, 25.0)
            + 0.03 * self.noise(rng, 6.0)
            + 0.035 * self.noise(rng, 1.5)
        )
        cheeks = self.bump(-40.0, 40.0, 14.0, 14.0) + self.bump(40.0, 40.0, 14.0, 14.0)
        redness = (
            0.04 * (1.0 + self.noise(rng, 15.0)) + 0.1 * cheeks + 0.08 * self.bump(0, 38, 8, 8)
        )
        self.rgb *= brightness[..., None]
        self.rgb *= 1.0 - redness[..., None] * np.array([0.0, 0.35, 0.3], np.float32)
        self.rgb *= 1.0 - 0.25 * self.speckle(rng, 0.012, 0.2)[..., None]
        for _ in range(int(rng.integers(3, 9))):
            centre = (rng.uniform(-60.0, 60.0), rng.uniform(-40.0, 110.0))
            mole = self.disc(centre, rng.uniform(0.5, 1.3), blur_mm=0.3)
            self.blend(0.6 * mole, appearance.skin * 0.45)

    def stubble(self, rng: np.random.Generator, appearance: Appearance) -> None:
        """Beard stubble (dense dark dots) on chin, jaw and upper lip, if the subject has any."""
        if appearance.stubble <= 0.0:
            return
        inside = outline_radius(np.stack([self.u, self.v], axis=-1)) < 0.8
        lower = np.clip((self.v - 55.0) / 10.0, 0.0, 1.0) * inside * (np.abs(self.u) < 62)
        region = np.clip(lower + self.bump(0.0, 57.0, 16.0, 2.5), 0.0, 1.0)
        region = cv2.GaussianBlur(region.astype(np.float32), (0, 0), 3.0 / ATLAS_MM_PER_PX)
        dots = self.speckle(rng, 0.05, 0.15)
        self.blend(0.6 * appearance.stubble * region * dots, appearance.hair)

    def hair(self, rng: np.random.Generator, appearance: Appearance) -> None:
        """Scalp hair above a hairline and over the ears, with strands."""
        u, v = self.u, self.v
        rho = outline_radius(np.stack([u, v], axis=-1))
        hairline = -72.0 + 0.014 * u**2
        region = ((v < hairline) | ((np.abs(u) > 68.0) & (v < 20.0))) & (rho < 1.05) & (u < 100)
        mask = cv2.GaussianBlur(region.astype(np.float32), (0, 0), 2.0 / ATLAS_MM_PER_PX)
        strands = cv2.blur(rng.standard_normal(self.shape).astype(np.float32), (3, 61))
        shade = 1.0 + 0.35 * strands / (strands.std() + 1e-6) + 0.15 * self.noise(rng, 20.0)
        self.blend(mask, appearance.hair * shade[..., None])

    def eyes(self, rng: np.random.Generator, appearance: Appearance) -> None:
        """Sclera, iris, pupil, catchlight, lids and lashes; almond corners = eye-corner nodes."""
        nodes = _reference_uv()
        inner, outer, centre = nodes['left_eye_inner'], nodes['left_eye_outer'], nodes['left_eye']
        upper_x = [inner[0], inner[0] + 6.0, centre[0], centre[0] + 8.5, outer[0]]
        upper_y = [inner[1], -3.8, -4.9, -3.4, outer[1]]
        lower_x = [inner[0], inner[0] + 8.0, centre[0] + 2.0, outer[0]]
        lower_y = [inner[1], 4.0, 4.3, outer[1]]
        iris_detail = 1.0 + 0.35 * self.noise(rng, 0.6)
        for side in (-1.0, 1.0):
            upper = _curve(upper_x, upper_y, side)
            lower = _curve(lower_x, lower_y, side)
            pupil_uv = (side * centre[0], centre[1])
            socket = self.bump(side * centre[0], 1.0, 14.0, 6.0)
            self.rgb *= 1.0 - 0.2 * socket[..., None]
            self.blend(0.3 * self.polyline(upper - [0.0, 5.0], 0.6, 0.3), appearance.skin * 0.5)
            almond = self.polygon(np.concatenate([upper, lower[::-1]]))
            self.blend(almond, (0.85, 0.83, 0.8))
            caruncle = self.bump(side * (inner[0] + 1.5), inner[1], 1.5, 1.2)
            self.blend(0.5 * almond * caruncle, (0.75, 0.45, 0.45))
            iris = almond * self.disc(pupil_uv, 5.6)
            self.blend(iris, appearance.iris * iris_detail[..., None])
            self.blend(almond * self.disc(pupil_uv, 2.1), (0.03, 0.03, 0.03))
            glint = (pupil_uv[0] + 1.6, pupil_uv[1] - 1.6)
            self.blend(almond * self.disc(glint, 0.7, 0.1), (0.97, 0.97, 0.97))
            self.blend(self.polyline(upper, 1.1), appearance.hair * 0.5)
            self.blend(0.6 * self.polyline(lower, 0.5), appearance.skin * 0.45)

    def brows(self, rng: np.random.Generator, appearance: Appearance) -> None:
        """Brows of hair strokes along inner, middle and outer brow nodes (their centre line)."""
        nodes = _reference_uv()
        inner, middle, outer = (
            nodes[f'left_brow_{part}'] for part in ('inner', 'middle', 'outer')
        )
        xs = [inner[0] - 3.0, inner[0], 25.0, middle[0], 41.0, outer[0], outer[0] + 2.5]
        ys = [inner[1] + 0.8, inner[1], -20.5, middle[1], -21.0, outer[1], outer[1] + 1.5]
        for side in (-1.0, 1.0):
            centre = _curve(xs, ys, side, count=200)
            t = np.linspace(0.0, 1.0, len(centre))
            half_width = 3.2 - 2.0 * t
            normal = np.gradient(centre, axis=0)[:, ::-1] * [-1.0, 1.0]
            normal /= np.linalg.norm(normal, axis=1, keepdims=True)
            band = np.concatenate(
                [
                    centre + half_width[:, None] * normal,
                    (centre - half_width[:, None] * normal)[::-1],
                ]
            )
            self.blend(0.45 * self.polygon(band, 0.6), appearance.hair)
            strokes = np.zeros(self.shape, np.uint8)
            for _ in range(260):
                k = int(rng.integers(len(centre)))
                offset = rng.uniform(-1.0, 1.0) * half_width[k]
                start = centre[k] + offset * normal[k]
                tangent = np.array([side * 1.0, -0.6 * (1.0 - t[k]) + rng.normal(0, 0.15)])
                end = start + rng.uniform(2.0, 4.0) * tangent / np.linalg.norm(tangent)
                cv2.line(strokes, *_px([start, end]), 255, 1, cv2.LINE_AA, _SHIFT)
            self.blend(0.8 * strokes.astype(np.float32) / 255.0, appearance.hair * 0.6)

    def nose_and_folds(self, appearance: Appearance) -> None:
        """Nostrils, ala creases through the nose-wing nodes, nasolabial folds, philtrum."""
        wing = _reference_uv()['nose_left']
        dark = appearance.skin * 0.35
        for side in (-1.0, 1.0):
            nostril = _px([(side * 7.5, wing[1] + 0.5)])[0]
            axes = (_radius(3.4), _radius(1.8))
            mask = self.draw(
                lambda layer, c=nostril, a=axes, s=side: cv2.ellipse(
                    layer, c, a, s * 25.0, 0, 360, 255, -1, cv2.LINE_AA, _SHIFT
                ),
                blur_mm=0.4,
            )
            self.blend(0.85 * mask, appearance.skin * 0.15)
            # The ala crease: an arc whose outermost point is the nose-wing node.
            angles = np.radians(np.linspace(-110.0, 100.0, 40))
            arc = np.stack(
                [side * (wing[0] - 5.0 + 5.0 * np.cos(angles)), wing[1] + 6.5 * np.sin(angles)], 1
            )
            self.blend(0.55 * self.polyline(arc, 0.7, 0.3), dark)
            fold = _curve(
                [wing[0] + 3.0, 25.0, 30.0, 31.5], [wing[1] + 1.0, 56.0, 66.0, 76.0], side
            )
            self.blend(0.25 * self.polyline(fold, 1.2, 1.0), dark)
            philtrum = np.array([[side * 4.5, 50.0], [side * 5.0, 61.0]])
            self.blend(0.12 * self.polyline(philtrum, 1.0, 0.8), dark)

    def mouth(self, rng: np.random.Generator, appearance: Appearance) -> None:
        """Lips between the lip-contour nodes, a dark mouth line and shadowed mouth corners."""
        nodes = _reference_uv()
        corner, upper_side, upper = (
            nodes['mouth_left'],
            nodes['upper_lip_left'],
            nodes['upper_lip'],
        )
        lower_side, lower = nodes['lower_lip_left'], nodes['lower_lip']
        line_x, line_y = [0.0, 12.0, corner[0]], [69.8, 69.3, corner[1]]
        upper_x = [upper[0], 5.0, upper_side[0], 18.0, corner[0]]
        upper_y = [upper[1], 61.2, upper_side[1], 66.2, corner[1]]
        lower_x, lower_y = (
            [lower[0], lower_side[0], 18.0, corner[0]],
            [lower[1], lower_side[1], 74.5, corner[1]],
        )
        shade = (1.0 + 0.08 * self.noise(rng, 0.8))[..., None]
        dark = appearance.skin * 0.3
        for top, bottom in ((upper_x, upper_y), (lower_x, lower_y)):
            left = _curve(top, bottom, 1.0)
            mouth_line = _curve(line_x, line_y, 1.0)
            outline = np.concatenate(
                [left, mouth_line[::-1], mouth_line * [-1, 1], (left * [-1, 1])[::-1]]
            )
            self.blend(0.9 * self.polygon(outline, 0.3), appearance.lips * shade)
        for side in (-1.0, 1.0):
            self.blend(0.9 * self.polyline(_curve(line_x, line_y, side), 0.7, 0.2), dark)
            self.blend(0.7 * self.disc((side * corner[0], corner[1]), 1.2, 0.6), dark)
