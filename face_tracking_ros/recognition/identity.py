"""Identity from the shape parameters sigma (seed §3.6, §4.5): an enrolment gallery and its rule.

Each enrolled person k is a Gaussian in sigma space, N(mu_k, C_k): mu_k is the mean of the sigma
samples given at enrolment and C_k their sample covariance plus a floor ``min_std**2 * I`` that
stands for the error of one track's sigma estimate, which a single enrolment track cannot show
(with sigma held fixed during tracking, §3.5, the sample covariance may even be zero). The best
enrolment samples are means over decision windows (what
:func:`~face_tracking_ros.recognition.evaluation.enroll_sequences` passes); per-frame estimates
also work but overstate the spread of a window mean (a more lenient, safe, C_k). A face is
observed for ``window`` seconds; the mean of its sigma estimates is assigned to the most likely
person (Gaussian maximum likelihood, i.e. the Mahalanobis nearest class with the
log-determinant term) and rejected as unknown when its squared Mahalanobis distance to that
person exceeds the chi-square quantile ``chi2.ppf(acceptance, p)``.

Why this rule and not an SVM (the seed cites SVMs for expressions): measured by
:func:`face_tracking_ros.recognition.evaluation.compare_identity_classifiers` in
:func:`~face_tracking_ros.recognition.benchmark.run_benchmark` (11 enrolled and 11 unknown
synthetic people, 1-s windows of sigma fitted to nodes with 1.5 mm tracking noise; default
preset with the true p = 4 bases / default preset with a learned p = 4 seed model / realistic
preset with a learned p = 4 joint model, both learned with q = 5 from 11 subjects' true meshes
with 0.5 mm noise, two 380-frame training sequences each), both rules are about equally accurate
on enrolled faces (closed set 100 / 100 / 100 % here, 100 / 100 / 100 % for an RBF SVM with
calibrated probabilities), but the SVM cannot reject strangers: its probabilities are relative
between enrolled people, so with a threshold set for the same acceptance of genuine faces it
rejected 8.6 / 21.4 / 27.3 % of the unknown windows, against 70.0 / 62.7 / 92.3 % here. (In that
benchmark sigma varies per frame without a per-track error, so the 2.5 mm floor, chosen for a
tracker that holds sigma per track, is generous; see ``IdentityConfig.min_std``.) The Gaussian
rule also enrols a new person without retraining and persists as small arrays.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
import math
import os

import numpy as np
from scipy.stats import chi2

from face_tracking_ros.errors import ConfigError, FieldError, InputError
from face_tracking_ros.recognition.archive import load_archive, model_header, save_archive
from face_tracking_ros.recognition.features import STAMP_TOLERANCE, SlidingWindow
from face_tracking_ros.recognition.gaussian import GaussianClasses
from face_tracking_ros.recognition.validation import check_shapes

GALLERY_KIND = 'identity_gallery'
GALLERY_FORMAT_VERSION = 1
UNKNOWN = 'unknown'
MAX_MIN_STD = 1.0  # m: a floor beyond a face's size tells no one apart
# m: entries whose mean sigma differ by no more are of the same estimates (summed in another
# order, their mean differs by rounding, ~1e-18 m); two tracks differ by millimetres.
SAME_SIGMA = 1e-12


@dataclass(frozen=True)
class IdentityConfig:
    """Tunables of identity recognition.

    Attributes:
        min_std: floor on each person's per-axis sigma standard deviation, same unit as sigma
            (metres), at most 1 m; added as ``min_std**2 * I`` to C_k when a person is enrolled
            (a gallery file keeps the floor of its enrolments: ``enroll --min-std``). It stands
            for the error of one track's sigma estimate, which one enrolment track cannot show:
            the mono tracker holds sigma fixed per track once its first views are adjusted, and
            two tracks of the same synthetic person (before that adjustment) differed by (0.9,
            2.9, 3.2, 1.5) mm RMS per component (p = 4), i.e. per-track errors of about (0.6,
            2.1, 2.3, 1.0) mm. With those errors
            (:func:`~face_tracking_ros.recognition.benchmark.identity_with_track_error`, default
            population, 11 enrolled, 500 strangers) 2.5 mm and acceptance 0.99 gave 98.6 %
            genuine faces right and 94.6 % strangers rejected (1.5 mm: 74.5 % and 99.4 %;
            3 mm at acceptance 0.999: 99.5 % and 83.4 %).
        acceptance: probability that a genuine face is accepted; the rejection threshold on the
            squared Mahalanobis distance is ``chi2.ppf(acceptance, p)``; in (0, 1).
        window: seconds of sigma estimates averaged for one decision (1 s in issue 7).
    """

    min_std: float = 2.5e-3
    acceptance: float = 0.99
    window: float = 1.0

    def __post_init__(self) -> None:
        """Validate the ranges.

        Raises:
            ConfigError: naming the parameter out of range.
        """
        if not 0.0 < self.min_std <= MAX_MIN_STD:
            expected = f'in (0, {MAX_MIN_STD}] m'
            raise FieldError(
                f'identity min_std must be {expected}, got {self.min_std}', 'min_std', expected
            )
        if not 0.0 < self.acceptance < 1.0:
            expected = 'in (0, 1)'
            msg = f'identity acceptance must be {expected}, got {self.acceptance}'
            raise FieldError(msg, 'acceptance', expected)
        if not STAMP_TOLERANCE < self.window < math.inf:
            expected = f'> {STAMP_TOLERANCE} s and finite'
            raise FieldError(
                f'identity window must be {expected}, got {self.window}', 'window', expected
            )

    def threshold(self, p: int) -> float:
        """Largest accepted squared Mahalanobis distance in a p-dimensional sigma space."""
        return float(chi2.ppf(self.acceptance, p))


@dataclass(frozen=True)
class IdentityDecision:
    """The identity decided for one window of sigma estimates.

    Attributes:
        identity: the enrolled name, or :data:`UNKNOWN` when rejected.
        nearest: the most likely enrolled name (also when rejected).
        distance: Mahalanobis distance (not squared) of the window's mean sigma to ``nearest``.
        confidence: in [0, 1]; for an accepted face the posterior of ``nearest`` among the
            enrolled people (equal priors); for a rejected face the chi-square probability that
            a genuine face of ``nearest`` lies closer, ``chi2.cdf(distance**2, p)``.
    """

    identity: str
    nearest: str
    distance: float
    confidence: float


@dataclass(frozen=True)
class IdentityGallery:
    """Enrolled people as Gaussians in sigma space.

    Attributes:
        p: dimension of sigma (the face model's p).
        names: K enrolled names.
        means: (K, p) mean sigma mu_k of each person.
        covariances: (K, p, p) covariance C_k of each person, floor included.
        counts: (K,) number of sigma estimates each person was enrolled from.
        model: fingerprint of the face model whose sigma it holds
            (:attr:`~face_tracking_ros.model.face_model.FaceModel.fingerprint`); None: not known.
    """

    p: int
    names: tuple[str, ...]
    means: np.ndarray
    covariances: np.ndarray
    counts: np.ndarray
    model: str | None = None

    def __post_init__(self) -> None:
        """Check that the arrays agree with p and the names.

        Raises:
            InputError: if a shape disagrees, a name repeats or a covariance is not SPD.
        """
        k = len(self.names)
        check_shapes(
            'gallery',
            self,
            {'means': (k, self.p), 'covariances': (k, self.p, self.p), 'counts': (k,)},
        )
        if len(set(self.names)) != k:
            msg = f'gallery names are not unique: {self.names}'
            raise InputError(msg)
        if np.any(self.counts < 1):
            msg = f'gallery counts must be >= 1 (estimates enrolled per person), got {self.counts}'
            raise InputError(msg)
        if k:
            _ = self.classes

    @classmethod
    def empty(cls, p: int, model: str | None = None) -> IdentityGallery:
        """A gallery for the p-dimensional sigma of ``model`` (a fingerprint) with nobody in."""
        return cls(
            p, (), np.zeros((0, p)), np.zeros((0, p, p)), np.zeros(0, dtype=np.int64), model
        )

    def __len__(self) -> int:
        """Number of enrolled people K."""
        return len(self.names)

    @cached_property
    def classes(self) -> GaussianClasses:
        """The people as Gaussian classes."""
        return GaussianClasses(means=self.means, covariances=self.covariances)

    def enroll(self, name: str, sigmas: np.ndarray, config: IdentityConfig) -> IdentityGallery:
        """A gallery with ``name`` enrolled from its sigma estimates (replacing an earlier entry).

        Args:
            name: the person's name; not empty, not :data:`UNKNOWN`.
            sigmas: (M, p) sigma samples of that person, M >= 1: decision-window means
                (best) or per-frame estimates.
            config: supplies ``min_std``.

        Raises:
            ConfigError: for an empty or reserved name.
            InputError: if sigmas is not a finite (M, p) array.
        """
        if not name.strip() or name == UNKNOWN:
            msg = f'cannot enrol an identity named {name!r}'
            raise ConfigError(msg)
        sigmas = _check_sigmas(sigmas, self.p)
        covariance = config.min_std**2 * np.eye(self.p)
        if len(sigmas) > 1:
            covariance += np.atleast_2d(np.cov(sigmas, rowvar=False))
        keep = [i for i, existing in enumerate(self.names) if existing != name]
        return IdentityGallery(
            p=self.p,
            names=(*(self.names[i] for i in keep), name),
            means=np.vstack([self.means[keep], sigmas.mean(axis=0)]),
            covariances=np.concatenate([self.covariances[keep], covariance[None]]),
            counts=np.append(self.counts[keep], len(sigmas)),
            model=self.model,
        )

    def enrolled_as(self, sigmas: np.ndarray) -> str | None:
        """The name of the entry these sigma estimates were enrolled as, if any.

        The entry of their mean sigma, to :data:`SAME_SIGMA`: enrolled under another name too,
        the two entries would tie in :meth:`classify` (the same mean; their spread the same
        unless enrolled with another ``min_std``).

        Args:
            sigmas: (M, p) sigma samples, as for :meth:`enroll`.

        Raises:
            InputError: if sigmas is not a finite (M, p) array.
        """
        mean = _check_sigmas(sigmas, self.p).mean(axis=0)
        same = np.all(np.abs(self.means - mean) <= SAME_SIGMA, axis=1)
        return next((name for name, hit in zip(self.names, same, strict=True) if hit), None)

    def classify(self, sigmas: np.ndarray, config: IdentityConfig) -> IdentityDecision:
        """Decide the identity of a face from its recent sigma estimates.

        Args:
            sigmas: (M, p) sigma estimates of one face (their mean is classified), or (p,).
            config: supplies the acceptance threshold.

        Raises:
            ConfigError: if the gallery is empty.
            InputError: if sigmas is not finite with p columns.
        """
        if not self.names:
            msg = 'the identity gallery is empty: enrol at least one person first'
            raise ConfigError(msg)
        mean_sigma = _check_sigmas(np.atleast_2d(sigmas), self.p).mean(axis=0, keepdims=True)
        best = int(np.argmax(self.classes.log_likelihoods(mean_sigma)[0]))
        distance_squared = float(self.classes.mahalanobis_squared(mean_sigma)[0, best])
        if distance_squared <= config.threshold(self.p):
            identity = self.names[best]
            confidence = float(self.classes.posteriors(mean_sigma)[0, best])
        else:
            identity = UNKNOWN
            confidence = float(chi2.cdf(distance_squared, self.p))
        return IdentityDecision(
            identity=identity,
            nearest=self.names[best],
            distance=float(np.sqrt(distance_squared)),
            confidence=confidence,
        )

    def save(self, path: str | os.PathLike[str]) -> None:
        """Write the gallery atomically (pickle-free npz, see :mod:`.archive`).

        Raises:
            ConfigError: if the gallery is empty (an empty file could never be used).
        """
        if not self.names:
            msg = f'refusing to save an empty identity gallery to {path}'
            raise ConfigError(msg)
        save_archive(
            path,
            GALLERY_KIND,
            GALLERY_FORMAT_VERSION,
            {'p': self.p, 'names': list(self.names), **model_header(self.model)},
            {'means': self.means, 'covariances': self.covariances, 'counts': self.counts},
        )

    @classmethod
    def load(
        cls, path: str | os.PathLike[str], p: int, model: str | None = None
    ) -> IdentityGallery:
        """Read a gallery written by :meth:`save` for a model with p shape parameters.

        Args:
            path: the gallery file.
            p: the model's p.
            model: the model's fingerprint; a gallery enrolled with another model is refused.
                None: not checked.

        Raises:
            ModelFileError: naming the file if it is missing, corrupt, empty, of another format
                version, or made for another p (both p named) or another model.
        """
        archive = load_archive(path, GALLERY_KIND, GALLERY_FORMAT_VERSION)
        file_p = archive.field('p', int)
        if file_p != p:
            archive.fail(f'gallery is for sigma of dimension p={file_p}, the model has p={p}')
        recorded = archive.model(
            model, 'its sigma means nothing to this model; enrol the people again with it'
        )
        names = archive.field('names', list)
        if not names:
            archive.fail('gallery holds no enrolled identities')
        if not all(isinstance(name, str) for name in names):
            archive.fail(f'gallery names must be text, got {names}')
        k = len(names)
        arrays = {
            'means': archive.array('means', (k, p)),
            'covariances': archive.array('covariances', (k, p, p)),
            'counts': archive.array('counts', (k,)).astype(np.int64),
        }
        try:
            return cls(p=p, names=tuple(names), **arrays, model=recorded)
        except InputError as error:
            problem = str(error)
        archive.fail(problem)


class IdentityRecognizer:
    """Per-face identity over a sliding window of sigma estimates.

    Feed every new sigma estimate of one tracked face with :meth:`update`; once the window spans
    ``config.window`` seconds each update returns the decision on the window's mean sigma.
    :meth:`enroll` adds the face being tracked to the gallery from the same window.
    """

    def __init__(self, gallery: IdentityGallery, config: IdentityConfig) -> None:
        """Start with an empty history.

        Args:
            gallery: enrolled people (may be empty until :meth:`enroll` is called).
            config: decision window, floor and acceptance.
        """
        self._gallery = gallery
        self._config = config
        self._window = SlidingWindow(config.window, gallery.p)

    @property
    def gallery(self) -> IdentityGallery:
        """The current gallery (it grows with :meth:`enroll`)."""
        return self._gallery

    def reset(self) -> None:
        """Forget the history, e.g. when the tracker restarts on a new face."""
        self._window.clear()

    def update(self, stamp: float, sigma: np.ndarray) -> IdentityDecision | None:
        """Add one sigma estimate and decide if the window is full.

        Args:
            stamp: time of the estimate, s; a stamp not later than the previous one starts a new
                history (a restarted tracker or a looped bag).
            sigma: (p,) shape parameters.

        Returns:
            The decision, or None while less than ``window`` seconds have been seen since the
            history started, or when the gallery is empty.

        Raises:
            InputError: if sigma is not a finite (p,) vector.
        """
        self._window.push(stamp, sigma)
        if self._window.elapsed < self._config.window - STAMP_TOLERANCE or not len(self._gallery):
            return None
        return self._gallery.classify(self._window.values, self._config)

    def enroll(self, name: str) -> IdentityGallery:
        """Enrol the face being tracked under ``name`` from the current window.

        Raises:
            ConfigError: if no sigma has been seen since the last reset, or for a bad name.
        """
        values = self._window.values
        if not len(values):
            msg = f'cannot enrol {name!r}: no shape estimate of the tracked face yet'
            raise ConfigError(msg)
        self._gallery = self._gallery.enroll(name, values, self._config)
        return self._gallery


def _check_sigmas(sigmas: np.ndarray, p: int) -> np.ndarray:
    """Return sigmas as a finite float (M, p) array with M >= 1, or raise InputError."""
    sigmas = np.asarray(sigmas, dtype=float)
    if sigmas.ndim != 2 or sigmas.shape[1] != p or len(sigmas) == 0:
        msg = f'sigma estimates must be an (M >= 1, p={p}) array, got shape {sigmas.shape}'
        raise InputError(msg)
    if not np.all(np.isfinite(sigmas)):
        msg = 'sigma estimates hold NaN or Inf'
        raise InputError(msg)
    return sigmas
