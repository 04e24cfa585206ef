"""Init files and the model fit to 2-D points (tracking.initialisation)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from face_tracking_ros.errors import ConfigError, InputError
from face_tracking_ros.geometry.camera import PinholeCamera
from face_tracking_ros.tracking.initialisation import (
    FitConfig,
    Initialisation,
    fit_model_to_points,
    load_init_file,
)
from face_tracking_ros.tracking.projection import project_with_jacobian

CAMERA = PinholeCamera.ideal()
SIX = ('right_eye', 'left_eye', 'nose_tip', 'mouth_right', 'mouth_left', 'chin')


def test_yaml_and_json_init_files_parse(tmp_path: Path) -> None:
    text = (
        '# first frame of the bag\n'
        'nodes:\n'
        + ''.join(
            f'  {name}: [{100 + 10 * i}.5, {200 + 15 * (i % 3)}]\n' for i, name in enumerate(SIX)
        )
        + 'sigma: [0.004, -0.001]\n'
    )
    yaml_path = tmp_path / 'init.yaml'
    yaml_path.write_text(text)
    init = load_init_file(yaml_path)
    assert init.node_names == SIX
    assert np.array_equal(init.points[2], [120.5, 230.0])
    assert np.array_equal(init.sigma, [0.004, -0.001])
    json_path = tmp_path / 'init.json'
    json_path.write_text(json.dumps({'nodes': dict(zip(SIX, init.points.tolist(), strict=True))}))
    from_json = load_init_file(json_path)
    assert from_json.sigma is None and np.array_equal(from_json.points, init.points)


@pytest.mark.parametrize(
    ('text', 'match'),
    [
        ('nodes: [1, 2]\n', 'expected a mapping with a "nodes" mapping'),
        ('nodes: {a: [1, 2]}\nextra: 1\n', r"unknown keys \['extra'\]"),
        ('nodes: {right_eye: [1, 2, 3]}\n', "node 'right_eye' must be \\[x, y\\]"),
        ('nodes: {right_eye: [1, true]}\n', "node 'right_eye' must be \\[x, y\\]"),
        ('nodes: {right_eye: [1, 2]}\n', 'at least 6 nodes, got 1'),
        ('nodes: {a: [1, 2]}\nsigma: oops\n', 'sigma must be a list of numbers'),
        ('nodes: {a: [1, 2]\n', 'is not valid YAML'),
        ('nodes:\n  a: [1, 2]\n\tb: [3, 4]\n', r"found character '\\t' that cannot start"),
        # An integer past float's range: float() raised OverflowError
        (f'nodes: {{right_eye: [{10**400}, 2]}}\n', "node 'right_eye' must be \\[x, y\\]"),
        (f'nodes: {{a: [1, 2]}}\nsigma: [{10**400}]\n', 'sigma must be a list of numbers'),
        # A node clicked twice: the second position was taken without a word
        ('nodes:\n  a: [1, 2]\n  b: [3, 4]\n  a: [5, 6]\n', "found key 'a' twice"),
        # A list as a key: the check for keys given twice raised TypeError (unhashable)
        ('nodes:\n  ? [1, 2]\n  : [3, 4]\n', 'not valid YAML: .*found unhashable key'),
        # One past Python's limit on parsing integers: its ValueError came out of the parser
        (f'nodes: {{right_eye: [{"1" * 5000}, 2]}}\n', 'not valid YAML: Exceeds the limit'),
    ],
)
def test_bad_init_files_name_the_file_and_problem(tmp_path: Path, text: str, match: str) -> None:
    path = tmp_path / 'bad.yaml'
    path.write_text(text)
    with pytest.raises(ConfigError, match=match) as info:
        load_init_file(path)
    assert str(path) in str(info.value) and '\n' not in str(info.value)  # one line


def test_missing_init_file(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match='cannot read init file .*nope.yaml'):
        load_init_file(tmp_path / 'nope.yaml')


def test_an_image_given_as_init_file_is_named_so(tmp_path: Path) -> None:
    path = tmp_path / 'frame.png'
    path.write_bytes(b'\x89PNG\r\n\x1a\n\xff\xfe')
    with pytest.raises(ConfigError, match=r'init file .*frame.png is not text \(UTF-8\)'):
        load_init_file(path)


def test_initialisation_validation(model_factory) -> None:
    points = np.array([[300, 200], [340, 200], [320, 230], [305, 260], [335, 260], [320, 290.0]])
    with pytest.raises(ConfigError, match='repeats node names'):
        Initialisation(('a',) * 6, points)
    with pytest.raises(ConfigError, match='points of left_eye, chin are not finite numbers'):
        Initialisation(SIX, np.where([[0], [1], [0], [0], [0], [1]], np.nan, points))
    for degenerate in (np.zeros((6, 2)), np.column_stack([np.arange(6.0), np.zeros(6)])):
        with pytest.raises(ConfigError, match='lie on one spot or one line'):
            Initialisation(SIX, degenerate)
    # Clicks zigzagging about a line, +-1.5 px (1.43 px RMS across it) or +-0.8 px (0.76 px):
    # the first still place a face seen edge-on, the second are one line (MIN_SPREAD_PX = 1).
    zigzag = (-1.0) ** np.arange(6)
    Initialisation(SIX, np.column_stack([40.0 * np.arange(6), 1.5 * zigzag]))
    with pytest.raises(ConfigError, match=r'one line \(0\.76 px RMS across it\)'):
        Initialisation(SIX, np.column_stack([40.0 * np.arange(6), 0.8 * zigzag]))
    with pytest.raises(ConfigError, match='sigma holds NaN'):
        Initialisation(SIX, points, sigma=np.array([np.inf]))
    model = model_factory(num_nodes=19)
    with pytest.raises(ConfigError, match="unknown node name 'chin'"):
        Initialisation(SIX, points).node_indices(model)
    with pytest.raises(ConfigError, match=r'sigma has shape \(1,\), model p = 3'):
        Initialisation(SIX[:5] + ('nose_left',), points, sigma=np.ones(1)).node_indices(model)
    with pytest.raises(ConfigError, match=r'invalid FitConfig\.pixel_noise = 0\.0'):
        FitConfig(pixel_noise=0.0)


def _truth_points(model, omega, t, sigma, alpha, noise=0.0, seed=0):
    shape = model.shape(sigma, alpha)
    pixels = project_with_jacobian(CAMERA, omega, t, shape).pixels
    return (
        pixels + np.random.default_rng(seed).normal(0.0, noise, pixels.shape) if noise else pixels
    )


def test_fit_recovers_pose_and_parameters_from_exact_points(model_factory) -> None:
    model = model_factory()
    omega, t = np.array([0.1, -0.3, 0.05]), np.array([0.03, -0.02, 0.65])
    sigma, alpha = np.array([0.02, -0.01, 0.005]), np.array([0.01, 0.0, -0.008, 0.004])
    init = Initialisation(model.node_names, _truth_points(model, omega, t, sigma, alpha))
    fit = fit_model_to_points(model, CAMERA, init, FitConfig(prior_weight=0.0))
    assert fit.rms_px < 1e-6
    assert np.allclose(fit.omega, omega, atol=1e-6) and np.allclose(fit.t, t, atol=1e-6)
    assert np.allclose(fit.sigma, sigma, atol=1e-5) and np.allclose(fit.alpha, alpha, atol=1e-5)


def test_fit_with_noise_and_prior_beats_mean_shape_pnp(model_factory) -> None:
    model = model_factory()
    omega, t = np.array([-0.2, 0.4, 0.1]), np.array([-0.05, 0.04, 0.7])
    sigma = 1.5 * np.sqrt(model.shape_eigenvalues)
    alpha = np.zeros(model.q)
    errors = {'fit': [], 'pnp': []}
    for seed in range(5):
        points = _truth_points(model, omega, t, sigma, alpha, noise=0.5, seed=seed)
        init = Initialisation(model.node_names, points)
        fit = fit_model_to_points(model, CAMERA, init, FitConfig(pixel_noise=0.5))
        rigid = fit_model_to_points(
            model,
            CAMERA,
            Initialisation(model.node_names, points, sigma=np.zeros(model.p)),
            FitConfig(fit_alpha=False),
        )
        errors['fit'].append(np.degrees(np.abs(fit.omega - omega)).max())
        errors['pnp'].append(np.degrees(np.abs(rigid.omega - omega)).max())
    assert np.mean(errors['fit']) < 1.5
    assert np.mean(errors['fit']) < 0.5 * np.mean(errors['pnp'])


def test_the_fit_is_the_minimum_of_the_reprojection_and_prior_terms(model_factory) -> None:
    """At the fit, the gradient of the objective written out by hand vanishes.

    ``sum ||pi(R (mean + S sigma + A alpha) + t) - x||^2 / 0.5^2 + 2 (sigma' Sigma_s^-1 sigma
    + alpha' Sigma_a^-1 alpha)``, by central differences: measured 0.0018 at most, against 257
    for the prior terms' share (a fit without them leaves 483).
    """
    model = model_factory()
    omega, t = np.array([-0.2, 0.4, 0.1]), np.array([-0.05, 0.04, 0.7])
    sigma = 1.5 * np.sqrt(model.shape_eigenvalues)
    alpha = np.sqrt(model.action_eigenvalues) * [1.0, -1.0, 0.5, 0.0]
    points = _truth_points(model, omega, t, sigma, alpha, noise=0.5, seed=0)
    init = Initialisation(model.node_names, points)
    fit = fit_model_to_points(model, CAMERA, init, FitConfig(pixel_noise=0.5, prior_weight=2.0))
    p = model.p
    precisions = [np.linalg.inv(model.sigma_prior_covariance)]
    precisions.append(np.linalg.inv(model.alpha_prior_covariance))

    def terms(params: np.ndarray) -> tuple[float, float]:
        coefficients = params[6 : 6 + p], params[6 + p :]
        shape = model.shape(*coefficients)
        pixels = project_with_jacobian(CAMERA, params[:3], params[3:6], shape).pixels
        prior = sum(
            c @ precision @ c for c, precision in zip(coefficients, precisions, strict=True)
        )
        return float(np.sum((pixels - points) ** 2) / 0.25), 2.0 * float(prior)

    def gradient(part) -> np.ndarray:
        params = np.concatenate([fit.omega, fit.t, fit.sigma, fit.alpha])
        steps = 1e-7 * np.maximum(np.abs(params), 1e-3)
        return np.array(
            [
                (part(params + step * unit) - part(params - step * unit)) / (2 * step)
                for step, unit in zip(steps, np.eye(params.size), strict=True)
            ]
        )

    prior_share = np.abs(gradient(lambda params: terms(params)[1])).max()
    assert prior_share > 100.0
    assert np.abs(gradient(lambda params: sum(terms(params)))).max() < 1e-3 * prior_share


def test_fit_with_enrolled_sigma_and_subset(model_factory) -> None:
    model = model_factory()
    omega, t = np.array([0.0, 0.2, 0.0]), np.array([0.0, 0.0, 0.6])
    sigma = np.array([0.01, 0.01, -0.01])
    pixels = _truth_points(model, omega, t, sigma, np.zeros(model.q))
    indices = [0, 1, 2, 5, 6, 11, 19, 22, 28]
    names = tuple(model.node_names[i] for i in indices)
    fit = fit_model_to_points(model, CAMERA, Initialisation(names, pixels[indices], sigma=sigma))
    assert np.array_equal(fit.sigma, sigma)
    assert fit.rms_px < 0.05 and np.allclose(fit.omega, omega, atol=2e-3)


def test_fit_rejects_points_no_face_fits_or_outside_the_image(model_factory) -> None:
    model = model_factory()
    pixels = _truth_points(model, np.zeros(3), np.array([0.0, 0.0, 0.6]), None, None)
    shuffled = pixels[np.random.default_rng(0).permutation(len(pixels))]
    with pytest.raises(InputError, match=r'RMS error .* px > 10.0 px\); check the init points'):
        fit_model_to_points(model, CAMERA, Initialisation(model.node_names, shuffled))
    beyond = pixels + [CAMERA.width / 2, 0.0]  # clicks of a wider image
    outside = ', '.join(n for n, (x, _) in zip(model.node_names, beyond, strict=True) if x > 639)
    with pytest.raises(InputError, match=f'outside the 640x480 image: {outside}$'):
        fit_model_to_points(model, CAMERA, Initialisation(model.node_names, beyond))


@pytest.mark.parametrize('names', [SIX, None])
def test_points_named_with_left_and_right_swapped_are_refused(model_factory, names) -> None:
    """They fit the face turned round, seen from behind (six at about 1 px RMS: accepted)."""
    model = model_factory()
    names = names or model.node_names
    pixels = _truth_points(model, np.array([0.1, 0.3, 0.0]), np.array([0.0, 0.0, 0.6]), None, None)
    points = pixels[[model.node_names.index(name) for name in names]]
    right = fit_model_to_points(model, CAMERA, Initialisation(names, points))
    assert np.allclose(right.omega, [0.1, 0.3, 0.0], atol=1e-3)
    swap = {'right': 'left', 'left': 'right'}
    mirrored = tuple('_'.join(swap.get(p, p) for p in name.split('_')) for name in names)
    with pytest.raises(InputError, match=r'fit a face turned 1\d\d degrees away .* swapped\?'):
        fit_model_to_points(model, CAMERA, Initialisation(mirrored, points))


def test_a_json_init_file_giving_a_node_twice_is_refused(tmp_path: Path) -> None:
    """json, as YAML, kept the second position of a node given twice without a word."""
    path = tmp_path / 'init.json'
    path.write_text('{"nodes": {"right_eye": [1, 2], "left_eye": [3, 4], "right_eye": [5, 6]}}')
    with pytest.raises(ConfigError, match="is not valid JSON: key 'right_eye' given twice"):
        load_init_file(path)
