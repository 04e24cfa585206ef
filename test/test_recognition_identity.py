"""Identity gallery: Gaussian rule against hand computations, recognition rates, file, errors."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from recognition_streams import sigma_population, sigma_stream
from scipy.spatial.distance import mahalanobis
from scipy.stats import chi2, multivariate_normal

from face_tracking_ros.errors import ConfigError, InputError, ModelFileError
from face_tracking_ros.model.model_file import save_model
from face_tracking_ros.recognition.archive import save_archive
from face_tracking_ros.recognition.gaussian import GaussianClasses
from face_tracking_ros.recognition.identity import (
    GALLERY_FORMAT_VERSION,
    GALLERY_KIND,
    UNKNOWN,
    IdentityConfig,
    IdentityGallery,
    IdentityRecognizer,
)
from face_tracking_ros.synthetic.faces import FacePopulation
from face_tracking_ros.synthetic.true_model import true_face_model

P = 4
# sigma std of the default synthetic population: sqrt(34) x (9, 6, 3.5, 2.5) mm RMS per node.
STDS = tuple(np.sqrt(34) * np.array([9.0, 6.0, 3.5, 2.5]) * 1e-3)
CONFIG = IdentityConfig()


def enrolled(rng: np.random.Generator, subjects: int, noise: float) -> tuple:
    """A gallery of subjects enrolled from 10 s of noisy sigma each, and their true sigma."""
    truth = sigma_population(rng, subjects, STDS)
    gallery = IdentityGallery.empty(P)
    for i, sigma in enumerate(truth):
        gallery = gallery.enroll(f'person_{i}', sigma_stream(rng, sigma, 10.0, noise), CONFIG)
    return gallery, truth


def test_rule_matches_hand_computed_mahalanobis_and_chi_square() -> None:
    rng = np.random.default_rng(0)
    samples = rng.normal(size=(50, P)) * 0.002 + 0.01
    gallery = IdentityGallery.empty(P).enroll('ann', samples, CONFIG)
    covariance = np.cov(samples, rowvar=False) + CONFIG.min_std**2 * np.eye(P)
    probe = samples.mean(axis=0) + np.array([0.004, -0.002, 0.001, 0.0])

    decision = gallery.classify(probe, CONFIG)

    expected = mahalanobis(probe, samples.mean(axis=0), np.linalg.inv(covariance))
    assert decision.distance == pytest.approx(expected, rel=1e-9)
    assert expected**2 < chi2.ppf(CONFIG.acceptance, P)
    assert decision.identity == 'ann'
    far = gallery.classify(probe + 0.05, CONFIG)
    assert far.identity == UNKNOWN
    assert far.nearest == 'ann'
    assert far.confidence == pytest.approx(chi2.cdf(far.distance**2, P))


def test_the_most_likely_person_wins_over_the_mahalanobis_nearest() -> None:
    """Maximum likelihood, with the log-determinant term, by hand; the window's mean decides.

    Ann is enrolled with a floor of 10 mm, Ben with 2.5 mm (one sample each: floors alone).
    The probe lies 20 mm from Ann (d^2 = 4) and 6.1 mm from Ben (d^2 = 6): Ben is less near but
    more likely, as log det C_Ann - log det C_Ben = 8 log 4. Posterior of Ben: the logistic of
    ``-0.5 (4 + log det C_Ann) + 0.5 (6 + log det C_Ben)`` negated.
    """
    ann, ben = np.zeros(P), np.zeros(P)
    ben[0] = 0.02 + np.sqrt(6.0) * 0.0025
    gallery = IdentityGallery.empty(P).enroll('ann', ann[None], replace(CONFIG, min_std=0.01))
    gallery = gallery.enroll('ben', ben[None], replace(CONFIG, min_std=0.0025))
    probe = np.array([0.02, 0.0, 0.0, 0.0])
    log_ratio = 0.5 * (6.0 - 4.0 - 2 * P * np.log(0.01 / 0.0025))  # ann's over ben's
    decision = gallery.classify(probe, CONFIG)
    assert (decision.identity, decision.nearest) == ('ben', 'ben')
    assert decision.distance == pytest.approx(np.sqrt(6.0), rel=1e-12)
    assert decision.confidence == pytest.approx(1.0 / (1.0 + np.exp(log_ratio)), rel=1e-12)
    # A window's mean is classified, not its last estimate (4 floors from ben: unknown).
    window = ben + np.array([[-0.01, 0.0, 0.0, 0.0], [0.01, 0.0, 0.0, 0.0]])
    assert gallery.classify(window, CONFIG).distance == pytest.approx(0.0, abs=1e-12)
    assert gallery.classify(window[-1], CONFIG).identity == UNKNOWN


def test_enrolled_mean_is_recognised_at_distance_zero() -> None:
    gallery, truth = enrolled(np.random.default_rng(1), 3, 0.002)

    decision = gallery.classify(gallery.means[1], CONFIG)

    assert decision.identity == 'person_1'
    assert decision.distance == 0.0
    densities = [
        multivariate_normal(mean, covariance).pdf(gallery.means[1])
        for mean, covariance in zip(gallery.means, gallery.covariances, strict=True)
    ]
    assert decision.confidence == pytest.approx(densities[1] / sum(densities), rel=1e-9)
    assert decision.confidence > 0.99


def test_gaussian_classes_match_scipy_densities_and_bayes_rule() -> None:
    rng = np.random.default_rng(7)
    means = rng.normal(size=(3, P))
    factors = rng.normal(size=(3, P, P))
    covariances = factors @ np.swapaxes(factors, 1, 2) + 0.5 * np.eye(P)
    classes = GaussianClasses(means, covariances)
    x = means[[0, 2]] + rng.normal(size=(2, P))

    expected = np.array(
        [
            [
                multivariate_normal(m, c).logpdf(row)
                for m, c in zip(means, covariances, strict=True)
            ]
            for row in x
        ]
    )

    np.testing.assert_allclose(classes.log_likelihoods(x), expected, rtol=1e-12)
    np.testing.assert_allclose(
        classes.posteriors(x), np.exp(expected) / np.exp(expected).sum(axis=1, keepdims=True)
    )
    assert classes.mahalanobis_squared(x).shape == (2, 3)
    empty = GaussianClasses(np.zeros((0, P)), np.zeros((0, P, P)))  # zero classes are allowed
    assert empty.mahalanobis_squared(x).shape == (2, 0)


def test_gaussian_classes_refuse_bad_input() -> None:
    classes = GaussianClasses(np.zeros((1, P)), np.eye(P)[None])
    with pytest.raises(InputError, match='NaN or Inf'):
        GaussianClasses(np.full((1, P), np.nan), np.eye(P)[None])
    with pytest.raises(InputError, match='NaN or Inf'):
        GaussianClasses(np.zeros((1, P)), np.full((1, P, P), np.inf))
    with pytest.raises(InputError, match=r'need \(K, d\) means and \(K, d, d\) covariances'):
        GaussianClasses(np.zeros((1, P)), np.eye(P))
    asymmetric = np.eye(P)[None].copy()
    asymmetric[0, 0, 1] = 0.1
    with pytest.raises(InputError, match='not symmetric'):
        GaussianClasses(np.zeros((1, P)), asymmetric)
    with pytest.raises(InputError, match='not positive definite'):
        GaussianClasses(np.zeros((1, P)), -np.eye(P)[None])
    for x in (np.zeros((1, P + 1)), np.full((1, P), np.nan), np.zeros(P)):
        with pytest.raises(InputError, match=r'features must be a finite \(M, 4\) array'):
            classes.mahalanobis_squared(x)


def test_eleven_subjects_recognised_after_one_second_and_strangers_rejected() -> None:
    rng = np.random.default_rng(2)
    gallery, truth = enrolled(rng, 11, 0.002)
    strangers = sigma_population(rng, 30, STDS)

    known = [
        gallery.classify(sigma_stream(rng, sigma, 1.0, 0.002), CONFIG).identity == f'person_{i}'
        for i, sigma in enumerate(truth)
        for _ in range(5)
    ]
    rejected = [
        gallery.classify(sigma_stream(rng, sigma, 1.0, 0.002), CONFIG).identity == UNKNOWN
        for sigma in strangers
    ]

    assert np.mean(known) >= 0.95
    assert np.mean(rejected) >= 0.9


def test_re_enrolment_replaces_the_person() -> None:
    rng = np.random.default_rng(3)
    gallery = IdentityGallery.empty(P).enroll('ann', rng.normal(size=(5, P)), CONFIG)
    gallery = gallery.enroll('bob', rng.normal(size=(5, P)), CONFIG)
    new_samples = rng.normal(size=(8, P)) + 3.0

    gallery = gallery.enroll('ann', new_samples, CONFIG)

    assert gallery.names == ('bob', 'ann')
    np.testing.assert_allclose(gallery.means[1], new_samples.mean(axis=0))
    assert list(gallery.counts) == [5, 8]


def test_single_sample_enrolment_uses_the_floor() -> None:
    gallery = IdentityGallery.empty(2).enroll('ann', np.zeros((1, 2)), CONFIG)

    np.testing.assert_allclose(gallery.covariances[0], CONFIG.min_std**2 * np.eye(2))


def test_file_round_trip_keeps_every_field_and_leaves_no_temporary(tmp_path: Path) -> None:
    gallery, _ = enrolled(np.random.default_rng(4), 3, 0.002)
    path = tmp_path / 'gallery.npz'

    gallery.save(path)
    loaded = IdentityGallery.load(path, P)

    assert loaded.names == gallery.names
    for name in ('means', 'covariances', 'counts'):
        np.testing.assert_array_equal(getattr(loaded, name), getattr(gallery, name))
    assert sorted(p.name for p in tmp_path.iterdir()) == ['gallery.npz']


def test_a_gallery_of_one_model_is_refused_with_another(tmp_path: Path) -> None:
    """Sigma of another model of the same p means another face: the gallery records its model."""
    gallery, _ = enrolled(np.random.default_rng(4), 3, 0.002)
    path = tmp_path / 'gallery.npz'
    replace(gallery, model='0123456789abcdef').save(path)

    assert IdentityGallery.load(path, P, '0123456789abcdef').model == '0123456789abcdef'
    assert IdentityGallery.load(path, P).model == '0123456789abcdef'  # unchecked: kept
    with pytest.raises(ModelFileError, match='another face model .fingerprint 0123456789abcdef'):
        IdentityGallery.load(path, P, 'fedcba9876543210')
    gallery.save(path)  # a gallery of an unknown model (before models were recorded)
    assert IdentityGallery.load(path, P, 'fedcba9876543210').model is None
    # Enrolling keeps the gallery's model.
    bound = IdentityGallery.empty(P, 'fedcba9876543210').enroll('ann', np.zeros((1, P)), CONFIG)
    assert bound.enroll('bob', np.ones((1, P)), CONFIG).model == 'fedcba9876543210'


def test_recognizer_waits_one_window_then_decides_and_enrols() -> None:
    rng = np.random.default_rng(5)
    gallery, truth = enrolled(rng, 3, 0.002)
    recognizer = IdentityRecognizer(gallery, CONFIG)
    stream = sigma_stream(rng, truth[2], 1.5, 0.002)
    stamps = 100.0 + np.arange(len(stream)) / 30.0

    decisions = [recognizer.update(t, s) for t, s in zip(stamps, stream, strict=True)]

    assert all(d is None for d in decisions[:30])
    assert all(d is not None and d.identity == 'person_2' for d in decisions[30:])
    newcomer = sigma_population(rng, 1, STDS)[0]
    recognizer.update(0.0, newcomer)  # an earlier stamp: a new face, the history restarts
    assert recognizer.update(0.5, newcomer) is None
    recognizer.enroll('carol')
    assert recognizer.gallery.classify(newcomer, CONFIG).identity == 'carol'
    assert recognizer.update(1.0, newcomer).identity == 'carol'


def test_empty_gallery_errors(tmp_path: Path) -> None:
    empty = IdentityGallery.empty(P)
    with pytest.raises(ConfigError, match='gallery is empty'):
        empty.classify(np.zeros(P), CONFIG)
    with pytest.raises(ConfigError, match='refusing to save an empty'):
        empty.save(tmp_path / 'g.npz')
    save_archive(
        tmp_path / 'g.npz',
        GALLERY_KIND,
        GALLERY_FORMAT_VERSION,
        {'p': P, 'names': []},
        {'means': np.zeros((0, P)), 'covariances': np.zeros((0, P, P)), 'counts': np.zeros(0)},
    )
    with pytest.raises(ModelFileError, match='no enrolled identities'):
        IdentityGallery.load(tmp_path / 'g.npz', P)
    recognizer = IdentityRecognizer(empty, CONFIG)
    assert recognizer.update(0.0, np.zeros(P)) is None
    with pytest.raises(ConfigError, match='no shape estimate'):
        IdentityRecognizer(empty, CONFIG).enroll('ann')


def test_file_errors(tmp_path: Path) -> None:
    gallery, _ = enrolled(np.random.default_rng(6), 2, 0.002)
    path = tmp_path / 'gallery.npz'
    gallery.save(path)
    with pytest.raises(ModelFileError, match=r'p=4, the model has p=3'):
        IdentityGallery.load(path, 3)
    with pytest.raises(ModelFileError, match='no such file'):
        IdentityGallery.load(tmp_path / 'missing.npz', P)
    with pytest.raises(ModelFileError, match='is a directory, not a file'):
        IdentityGallery.load(tmp_path, P)
    # A damaged central directory whose 'version needed to extract' reads 25.5.
    data = bytearray(path.read_bytes())
    entry = data.index(b'PK\x01\x02')
    data[entry + 6 : entry + 8] = b'\xff\x00'
    (tmp_path / 'version.npz').write_bytes(data)
    with pytest.raises(ModelFileError, match='not a readable pickle-free .npz archive'):
        IdentityGallery.load(tmp_path / 'version.npz', P)
    (tmp_path / 'corrupt.npz').write_bytes(path.read_bytes()[:200])
    with pytest.raises(ModelFileError, match='not an .npz archive, or a damaged one'):
        IdentityGallery.load(tmp_path / 'corrupt.npz', P)
    arrays = {
        'means': gallery.means,
        'covariances': -gallery.covariances,
        'counts': gallery.counts,
    }
    header = {'p': P, 'names': list(gallery.names)}
    save_archive(path, GALLERY_KIND, GALLERY_FORMAT_VERSION, header, arrays)
    with pytest.raises(ModelFileError, match='not positive definite'):
        IdentityGallery.load(path, P)
    save_archive(path, GALLERY_KIND, GALLERY_FORMAT_VERSION + 1, header, arrays)
    with pytest.raises(ModelFileError, match='format version 2; this code reads version 1'):
        IdentityGallery.load(path, P)
    save_archive(path, 'expression_classifier', 1, header, arrays)
    with pytest.raises(ModelFileError, match="holds a 'expression_classifier'"):
        IdentityGallery.load(path, P)
    save_model(true_face_model(FacePopulation('default'), 19), path)
    with pytest.raises(ModelFileError, match="holds a 'face_tracking_ros.face_model', expected"):
        IdentityGallery.load(path, P)
    narrow = {**arrays, 'covariances': gallery.covariances, 'means': gallery.means[:, :3]}
    save_archive(path, GALLERY_KIND, GALLERY_FORMAT_VERSION, header, narrow)
    with pytest.raises(ModelFileError, match=r"'means' has shape \(2, 3\), expected \(2, 4\)"):
        IdentityGallery.load(path, P)
    bad = {**arrays, 'covariances': gallery.covariances, 'counts': -gallery.counts}
    save_archive(path, GALLERY_KIND, GALLERY_FORMAT_VERSION, header, bad)
    with pytest.raises(ModelFileError, match=r'gallery counts must be >= 1'):
        IdentityGallery.load(path, P)
    save_archive(path, GALLERY_KIND, GALLERY_FORMAT_VERSION, {**header, 'names': [1, 2]}, arrays)
    with pytest.raises(ModelFileError, match=r'gallery names must be text, got \[1, 2\]'):
        IdentityGallery.load(path, P)


def test_input_and_config_errors() -> None:
    gallery = IdentityGallery.empty(P)
    with pytest.raises(ConfigError, match="named 'unknown'"):
        gallery.enroll(UNKNOWN, np.zeros((2, P)), CONFIG)
    with pytest.raises(InputError, match=r'\(M >= 1, p=4\)'):
        gallery.enroll('ann', np.zeros((2, 3)), CONFIG)
    with pytest.raises(InputError, match='NaN'):
        gallery.enroll('ann', np.full((2, P), np.nan), CONFIG)
    with pytest.raises(InputError, match='means has shape'):
        IdentityGallery(P, ('ann',), np.zeros((2, P)), np.zeros((1, P, P)), np.zeros(1))
    with pytest.raises(ConfigError, match=r"named '  '"):
        gallery.enroll('  ', np.zeros((2, P)), CONFIG)
    for min_std in (0.0, np.inf, 1e200, np.nan):
        with pytest.raises(ConfigError, match=r'min_std must be in \(0, 1.0\] m'):
            IdentityConfig(min_std=min_std)
    with pytest.raises(ConfigError, match='acceptance'):
        IdentityConfig(acceptance=1.0)
    for window in (-1.0, 1e-9, np.nan, np.inf):  # (1e-9: shorter than the stamp tolerance)
        with pytest.raises(ConfigError, match='identity window must be > 1e-06 s'):
            IdentityConfig(window=window)


def test_an_empty_gallery_decides_nothing_until_the_first_enrolment() -> None:
    rng = np.random.default_rng(6)
    recognizer = IdentityRecognizer(IdentityGallery.empty(P), CONFIG)
    sigma = sigma_population(rng, 1, STDS)[0]
    stream = sigma_stream(rng, sigma, 1.5, 0.002)
    stamps = np.arange(len(stream)) / 30.0
    assert all(recognizer.update(t, s) is None for t, s in zip(stamps, stream, strict=True))
    recognizer.enroll('ann')
    assert recognizer.update(stamps[-1] + 1 / 30.0, sigma).identity == 'ann'
