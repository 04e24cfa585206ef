"""Initialisation of the face model on an image from 2-D node positions (seed §3.5).

The seed initialises the mesh on the first frame semi-automatically. Here the 2-D positions of a
subset of named mesh nodes (at least :data:`MIN_INIT_NODES`) come from an init file, the
``ResetTracking`` service or a landmark detector, as an :class:`Initialisation`. A model fit then
turns them into the pose and parameters of eq. 1-3: ``cv2.solvePnP`` on the (identity) shape for
the pose, then a least-squares refinement of pose, sigma and alpha with the Gaussian priors of
§4.1.

Init file (YAML or JSON; node names are those of :mod:`face_tracking_ros.model.topology`)::

    # pixel positions (x = column, y = row) of mesh nodes in the first image
    nodes:
      right_eye: [281.5, 212.0]
      left_eye: [358.0, 211.2]
      nose_tip: [320.4, 262.9]
      mouth_right: [291.0, 300.7]
      mouth_left: [350.2, 300.1]
      chin: [321.0, 356.3]
    sigma: [0.004, -0.001]   # optional: a known (enrolled) identity, held fixed
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
import json
from pathlib import Path
import sys
from typing import Any

import cv2
import numpy as np
from scipy.linalg import block_diag, cholesky, solve_triangular
from scipy.optimize import least_squares
import yaml

from face_tracking_ros.errors import ConfigError, InputError, check_fields
from face_tracking_ros.geometry.camera import PinholeCamera
from face_tracking_ros.geometry.rotation import rodrigues
from face_tracking_ros.imaging import inside_image
from face_tracking_ros.io.yaml_text import parse_yaml_unique_keys
from face_tracking_ros.model.face_model import FaceModel
from face_tracking_ros.model.topology import mesh_topology
from face_tracking_ros.tracking.projection import POSE_DIM, project_with_jacobian
from face_tracking_ros.wording import counted

MIN_INIT_NODES = 6
MIN_SPREAD_PX = 1.0  # RMS spread of the points across their thinnest direction, px


@dataclass(frozen=True)
class Initialisation:
    """2-D positions of named mesh nodes in one image, and optionally a known identity.

    Attributes:
        node_names: K distinct node names, K >= 6.
        points: (K, 2) pixel positions (x = column, y = row), px.
        sigma: (p,) identity parameters to hold fixed (an enrolled identity), or None to fit them.
        source: where the positions come from, for messages (e.g. 'init file clicks.yaml').
    """

    node_names: tuple[str, ...]
    points: np.ndarray
    sigma: np.ndarray | None = None
    source: str = field(default='the initialisation', compare=False)

    def __post_init__(self) -> None:
        """Check counts, shapes and finiteness; errors name the problem."""
        count = len(self.node_names)
        if count < MIN_INIT_NODES:
            msg = f'initialisation needs at least {MIN_INIT_NODES} nodes, got {count}'
            raise ConfigError(msg)
        repeated = sorted({name for name in self.node_names if self.node_names.count(name) > 1})
        if repeated:
            msg = f'initialisation repeats node names: {", ".join(repeated)}'
            raise ConfigError(msg)
        if np.shape(self.points) != (count, 2):
            shape = np.shape(self.points)
            msg = f'initialisation points must be {count} (x, y) pairs, got shape {shape}'
            raise ConfigError(msg)
        finite = np.all(np.isfinite(self.points), axis=1)
        if not finite.all():
            names = [name for name, ok in zip(self.node_names, finite, strict=True) if not ok]
            msg = f'initialisation points of {", ".join(names)} are not finite numbers'
            raise ConfigError(msg)
        centred = self.points - self.points.mean(axis=0)
        spread = np.linalg.svd(centred, compute_uv=False)[-1] / np.sqrt(count)
        if spread < MIN_SPREAD_PX:
            msg = (
                f'initialisation points lie on one spot or one line ({spread:.2f} px RMS across '
                'it): they cannot place a face'
            )
            raise ConfigError(msg)
        if self.sigma is not None and not np.all(np.isfinite(self.sigma)):
            msg = f'initialisation sigma holds NaN or Inf: {self.sigma}'
            raise ConfigError(msg)

    def only(self, node_names: Sequence[str]) -> Initialisation:
        """The given nodes that are among ``node_names`` (e.g. 34-node clicks for 19 nodes).

        Raises:
            ConfigError: if fewer than :data:`MIN_INIT_NODES` remain.
        """
        wanted = set(node_names)
        keep = [i for i, name in enumerate(self.node_names) if name in wanted]
        names = tuple(self.node_names[i] for i in keep)
        return replace(self, node_names=names, points=self.points[keep])

    def unknown_nodes(self, node_names: Sequence[str], owner: str) -> str:
        """What names the given nodes that ``owner``'s ``node_names`` lack; '' if none.

        E.g. "init file a.yaml names 2 nodes (chin, ear) that the face model lacks (misspelt?
        its nodes: ...)".
        """
        missing = sorted(set(self.node_names) - set(node_names))
        if not missing:
            return ''
        listed = ', '.join(missing[:4]) + (', ...' if len(missing) > 4 else '')
        return (
            f'{self.source} names {counted(len(missing), "node")} ({listed}) that {owner} lacks '
            f'(misspelt? its nodes: {", ".join(node_names)})'
        )

    def moved(self, move: Callable[[np.ndarray], np.ndarray]) -> Initialisation:
        """The same nodes at ``move(points)``, e.g. from the raw to the rectified image."""
        return replace(self, points=move(self.points))

    @classmethod
    def from_mapping(
        cls, data: Mapping[str, Any], source: str = 'initialisation'
    ) -> Initialisation:
        """Build from the init-file mapping ``{'nodes': {name: [x, y]}, 'sigma': [...]}``.

        Raises:
            ConfigError: naming ``source`` and the faulty key or value.
        """
        if not isinstance(data, Mapping) or not isinstance(data.get('nodes'), Mapping):
            msg = f'{source}: expected a mapping with a "nodes" mapping of node name to [x, y]'
            raise ConfigError(msg)
        unknown = set(data) - {'nodes', 'sigma'}
        if unknown:
            msg = f'{source}: unknown keys {sorted(unknown)}; allowed: nodes, sigma'
            raise ConfigError(msg)
        names, points = [], []
        for name, value in data['nodes'].items():
            if not is_point(value):
                msg = f'{source}: node {name!r} must be [x, y] in pixels, got {value!r}'
                raise ConfigError(msg)
            names.append(str(name))
            points.append([float(v) for v in value])
        sigma = data.get('sigma')
        if sigma is not None and not _is_number_list(sigma):
            msg = f'{source}: sigma must be a list of numbers, got {sigma!r}'
            raise ConfigError(msg)
        try:
            return cls(
                node_names=tuple(names),
                points=np.array(points, dtype=float).reshape(-1, 2),
                sigma=None if sigma is None else np.array(sigma, dtype=float),
                source=source,
            )
        except ConfigError as error:
            raise ConfigError(f'{source}: {error}') from None

    def node_indices(self, model: FaceModel) -> np.ndarray:
        """(K,) indices of the named nodes in ``model``.

        Raises:
            ConfigError: naming a node the model does not have, or a sigma of the wrong length.
        """
        topology = mesh_topology(model.num_nodes)
        if self.sigma is not None and np.shape(self.sigma) != (model.p,):
            msg = f'initialisation sigma has shape {np.shape(self.sigma)}, model p = {model.p}'
            raise ConfigError(msg)
        return np.array([topology.index(name) for name in self.node_names], dtype=int)


def load_init_file(path: str | Path) -> Initialisation:
    """Read an init file (YAML, or JSON by the ``.json`` suffix); see the module docstring.

    Raises:
        ConfigError: if the file is missing, unparsable or malformed; the message names the file.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding='utf-8')
    except OSError as error:
        msg = f'cannot read init file {path}: {error.strerror}'
        raise ConfigError(msg) from None
    except UnicodeDecodeError:
        msg = f'init file {path} is not text (UTF-8): an image or another binary file?'
        raise ConfigError(msg) from None
    try:
        data = (
            json.loads(text, object_pairs_hook=unique_json_keys)
            if path.suffix.lower() == '.json'
            else parse_yaml_unique_keys(text)
        )
    except (ValueError, yaml.YAMLError) as error:  # json's, and an integer of > 4300 digits
        kind = 'JSON' if path.suffix.lower() == '.json' else 'YAML'
        msg = f'init file {path} is not valid {kind}: {" ".join(str(error).split())}'
        raise ConfigError(msg) from None
    return Initialisation.from_mapping(data, source=f'init file {path}')


def unique_json_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """A JSON object of ``pairs``; ValueError for a key given twice (json keeps the last)."""
    keys = [key for key, _ in pairs]
    twice = sorted({key for key in keys if keys.count(key) > 1})
    if twice:
        msg = f'key {twice[0]!r} given twice'
        raise ValueError(msg)
    return dict(pairs)


def is_point(value: Any) -> bool:
    """True for a 2-element list of numbers."""
    return _is_number_list(value) and len(value) == 2


def _is_number_list(value: Any) -> bool:
    """True for a list or tuple of floats and of ints a float can hold (not bools).

    YAML and JSON read any integer, such as a 400-digit one, which float() cannot convert.
    """
    return isinstance(value, list | tuple) and all(
        isinstance(v, float) or (isinstance(v, int) and not isinstance(v, bool) and _fits_float(v))
        for v in value
    )


def _fits_float(value: int) -> bool:
    """Whether float(value) is a number (not an OverflowError)."""
    return abs(value) <= sys.float_info.max


@dataclass(frozen=True)
class FitConfig:
    """Weights of the model fit to 2-D points.

    Attributes:
        pixel_noise: standard deviation of the given 2-D points, px (> 0); scales the
            reprojection residuals against the priors.
        prior_weight: multiplier of the §4.1 Gaussian priors on sigma and alpha (>= 0).
        fit_alpha: estimate alpha (expression) too; otherwise alpha = 0.
        max_rms_px: a fit whose RMS reprojection error exceeds this is rejected, px (> 0): the
            points do not look like a face of the model (wrong names, points swapped at
            random). Left and right swapped fit a face seen from behind, and are refused as
            such whatever its error.
    """

    pixel_noise: float = 2.0
    prior_weight: float = 1.0
    fit_alpha: bool = True
    max_rms_px: float = 10.0

    def __post_init__(self) -> None:
        """Validate every field; the error names the field and its value."""
        checks = {
            'pixel_noise': self.pixel_noise > 0,
            'prior_weight': self.prior_weight >= 0,
            'max_rms_px': self.max_rms_px > 0,
        }
        check_fields(self, checks)


@dataclass(frozen=True)
class ModelFit:
    """Pose and parameters of eq. 1-3 fitted to 2-D points.

    Attributes:
        omega: (3,) rotation vector, rad.
        t: (3,) translation, m.
        sigma: (p,) identity parameters.
        alpha: (q,) expression parameters.
        residuals_px: (K,) reprojection error of each given point, px.
    """

    omega: np.ndarray
    t: np.ndarray
    sigma: np.ndarray
    alpha: np.ndarray
    residuals_px: np.ndarray

    @property
    def rms_px(self) -> float:
        """RMS reprojection error, px."""
        return float(np.sqrt(np.mean(self.residuals_px**2)))


def fit_model_to_points(
    model: FaceModel,
    camera: PinholeCamera,
    init: Initialisation,
    config: FitConfig | None = None,
) -> ModelFit:
    """Fit pose, sigma and alpha of eq. 1-3 to 2-D node positions.

    Minimises ``sum_k ||x_k - pi(R (mean + S sigma + A alpha)_k + t)||^2 / pixel_noise^2 +
    prior_weight (sigma' Sigma_s^-1 sigma + alpha' Sigma_a^-1 alpha)`` with
    ``scipy.optimize.least_squares`` and the analytic Jacobian, starting from ``cv2.solvePnP``
    (SQPnP) on the identity shape (the mean shape unless ``init.sigma`` is given).

    Args:
        model: the face model (eq. 3) with its priors (§4.1).
        camera: the camera of the image the points were taken in.
        init: the 2-D points (and optionally a fixed sigma).
        config: weights; defaults to :class:`FitConfig()`.

    Returns:
        The :class:`ModelFit`.

    Raises:
        ConfigError: for node names the model lacks or a sigma of the wrong length.
        InputError: for points outside the image, if no pose puts the face in front of the
            camera within ``config.max_rms_px`` RMS, or if the fit faces away from the camera
            (left and right swapped).
    """
    config = config or FitConfig()
    check_inside(init.node_names, init.points, (camera.width, camera.height))
    sigma0 = np.zeros(model.p) if init.sigma is None else np.asarray(init.sigma, dtype=float)
    problem = _FitProblem.of(model, camera, init, sigma0, config)
    omega0, t0 = _pnp(problem.base_shape, init.points, camera)
    start = np.concatenate([omega0, t0, np.zeros(problem.coefficients)])
    solution = least_squares(
        problem.residuals, start, jac=problem.jacobian, method='lm', x_scale='jac'
    ).x
    omega, t, coefficient_values = solution[:3], solution[3:6], solution[POSE_DIM:]
    sigma = sigma0 if init.sigma is not None else coefficient_values[: model.p]
    alpha = (
        coefficient_values[problem.coefficients - model.q :]
        if config.fit_alpha
        else np.zeros(model.q)
    )
    pixels = project_with_jacobian(camera, omega, t, problem.shape(solution)).pixels
    fit = ModelFit(
        omega=omega,
        t=t,
        sigma=np.asarray(sigma, dtype=float).copy(),
        alpha=np.asarray(alpha, dtype=float).copy(),
        residuals_px=np.linalg.norm(pixels - init.points, axis=1),
    )
    if not (np.all(np.isfinite(solution)) and t[2] > 0 and fit.rms_px <= config.max_rms_px):
        msg = (
            f'model fit to {len(init.node_names)} points failed (t = {t} m, RMS error '
            f'{fit.rms_px:.1f} px > {config.max_rms_px} px); check the init points'
        )
        raise InputError(msg)
    _check_facing(fit)
    return fit


@dataclass(frozen=True)
class _FitProblem:
    """The least-squares problem of :func:`fit_model_to_points` over (omega, t, coefficients).

    The coefficients are sigma (unless the initialisation fixes it) then alpha (if fitted).

    Attributes:
        camera: the camera of the image the points were taken in.
        points: (K, 2) the given nodes' pixel positions.
        base_shape: (K, 3) the given nodes of the identity shape the coefficients start from.
        basis: (K, 3, C) the given nodes' rows of the fitted bases; None when nothing is.
        prior: (C, C) sqrt(prior_weight) times the whitening of the coefficients' priors.
        pixel_noise: the points' standard deviation, px.
    """

    camera: PinholeCamera
    points: np.ndarray
    base_shape: np.ndarray
    basis: np.ndarray | None
    prior: np.ndarray
    pixel_noise: float

    @classmethod
    def of(
        cls,
        model: FaceModel,
        camera: PinholeCamera,
        init: Initialisation,
        sigma0: np.ndarray,
        config: FitConfig,
    ) -> _FitProblem:
        """The problem of fitting ``model`` to ``init``'s points from the identity ``sigma0``."""
        indices = init.node_indices(model)
        sigma_fixed = init.sigma is not None
        bases = [model.shape_basis_nodes()[indices]] if not sigma_fixed else []
        whitening = [_whitening(model.sigma_prior_covariance)] if not sigma_fixed else []
        if config.fit_alpha:
            bases.append(model.action_basis_nodes()[indices])
            whitening.append(_whitening(model.alpha_prior_covariance))
        return cls(
            camera=camera,
            points=init.points,
            base_shape=model.identity_shape(sigma0)[indices],
            basis=np.concatenate(bases, axis=-1) if bases else None,
            prior=np.sqrt(config.prior_weight)
            * (block_diag(*whitening) if whitening else np.zeros((0, 0))),
            pixel_noise=config.pixel_noise,
        )

    @property
    def coefficients(self) -> int:
        """C, the number of fitted coefficients."""
        return 0 if self.basis is None else self.basis.shape[-1]

    def shape(self, params: np.ndarray) -> np.ndarray:
        """Face-frame points of the given nodes for the coefficients in ``params`` (eq. 3)."""
        if self.basis is None:
            return self.base_shape
        return self.base_shape + self.basis @ params[POSE_DIM:]

    def residuals(self, params: np.ndarray) -> np.ndarray:
        """Whitened reprojection errors (eq. 1, 2), then the whitened coefficients."""
        pixels = project_with_jacobian(
            self.camera, params[:3], params[3:6], self.shape(params)
        ).pixels
        reprojection = (pixels - self.points).ravel() / self.pixel_noise
        return np.concatenate([reprojection, self.prior @ params[POSE_DIM:]])

    def jacobian(self, params: np.ndarray) -> np.ndarray:
        """The derivative of :meth:`residuals` in ``params``."""
        projection = project_with_jacobian(
            self.camera, params[:3], params[3:6], self.shape(params), self.basis
        )
        data = projection.jacobian.reshape(-1, params.size) / self.pixel_noise
        prior_rows = np.hstack([np.zeros((self.prior.shape[0], POSE_DIM)), self.prior])
        return np.vstack([data, prior_rows])


def check_inside(
    names: Sequence[str], points: np.ndarray, size: tuple[int, int], image: str = 'image'
) -> None:
    """Refuse given node positions outside an image of ``size`` (width, height).

    Args:
        names: the nodes' names.
        points: (K, 2) their pixel positions; a NaN row is a node not given.
        size: the image's width and height, px.
        image: the image, for the message (e.g. 'left image').

    Raises:
        InputError: naming the nodes outside.
    """
    width, height = size
    outside = np.all(np.isfinite(points), axis=1) & ~inside_image(points, (height, width))
    if outside.any():
        named = ', '.join(name for name, out in zip(names, outside, strict=True) if out)
        msg = f'initial node positions outside the {width}x{height} {image}: {named}'
        raise InputError(msg)


def _check_facing(fit: ModelFit) -> None:
    """Refuse a fitted face turned away from the camera (more than 90 degrees from it).

    A face is nearly symmetric, so points named with left and right swapped (the subject's left
    is the image's right) fit it about as well turned round, seen from behind: six such clicks
    fitted at 0.3-1.3 px RMS, 34 at 1.9-2.8 px, the face turned 143-172 degrees from the camera
    (the right names: 12-34 degrees, at random poses of the default model).

    Raises:
        InputError: saying so.
    """
    rotation, _ = rodrigues(fit.omega)
    toward = float(rotation[:, 2] @ fit.t / np.linalg.norm(fit.t))  # face z along the view ray
    if toward < 0.0:
        turned = np.degrees(np.arccos(max(toward, -1.0)))
        msg = (
            f'the init points fit a face turned {turned:.0f} degrees away from the camera: are '
            "left and right swapped? The subject's left eye (left_eye) is on the image's right"
        )
        raise InputError(msg)


def _pnp(shape: np.ndarray, points: np.ndarray, camera: PinholeCamera) -> tuple[np.ndarray, ...]:
    """Pose (omega, t) of ``shape`` (K, 3) seen at ``points`` (K, 2), by SQPnP then refinement."""
    intrinsics = camera.p[:, :3]
    try:
        found, rvec, tvec = cv2.solvePnP(
            shape, points.astype(float), intrinsics, None, flags=cv2.SOLVEPNP_SQPNP
        )
    except cv2.error as error:  # a degenerate shape or calibration
        msg = f'solvePnP cannot place the face model at the init points: {error.err}'
        raise InputError(msg) from None
    if not found or tvec[2, 0] <= 0:
        msg = 'solvePnP found no pose in front of the camera for the init points'
        raise InputError(msg)
    rvec, tvec = cv2.solvePnPRefineLM(shape, points.astype(float), intrinsics, None, rvec, tvec)
    return rvec.ravel(), tvec.ravel()


def _whitening(covariance: np.ndarray) -> np.ndarray:
    """W with W' W = covariance^-1 (inverse Cholesky factor); a tiny ridge keeps it finite."""
    ridge = 1e-12 * max(float(np.trace(covariance)), 1e-30)
    lower = cholesky(covariance + ridge * np.eye(len(covariance)), lower=True)
    return solve_triangular(lower, np.eye(len(covariance)), lower=True)
