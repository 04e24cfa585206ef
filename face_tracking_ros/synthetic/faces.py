"""Ground-truth face population of the synthetic world: identities and expressions on 34 nodes.

Every synthetic face is eq. 3 with TRUE bases::

    X = mean_shape + identity_basis_true @ sigma_true + expression_basis_true @ alpha_true

on the 34-node mesh of §4.1 (:func:`~face_tracking_ros.model.topology.mesh_topology`), flattened
node-major to (102,) in the face frame, metres. The 19-node mesh of §3.2 keeps the first 19 nodes
(the first 57 rows); :meth:`FacePopulation.truth` restricts everything to it.

Truth parameterisation (what ``truth/face`` carries, and what learned models are scored against):

- ``identity_basis_true`` (102, K): one column per identity mode, ordered by decreasing
  variance; ``sigma_true`` (K,) of a subject is drawn independently per mode from a zero-mean
  normal truncated at about +-2.3 std (no caricatures) with variance ``identity_variances_true``,
  m^2. Each column comes from a named, anatomically smooth deformation (face width, face length,
  nose projection, jaw width, eye spacing, brow height, lip fullness, ...), Gram-Schmidt
  orthonormalised in the preset's order on the preset's mesh: all 34 nodes ('default') or the
  seed's 19 nodes ('realistic'), the columns carrying the same combinations of the fields to the
  other nodes. On that mesh the columns are orthonormal and are the principal axes of the
  identity covariance, with the preset's figures as its spectrum.
- ``expression_basis_true`` (102, E) holds one displacement field per named non-neutral
  expression (:data:`EXPRESSIONS` without 'neutral'), each at full intensity (the same fields
  in both presets, scaled by the preset); its columns are not orthonormal. ``alpha_true`` (E,)
  is the intensity of each expression, in [0, 1].
- A learned model has its own bases, mean and parameters; compare subspaces (e.g. the top-p
  principal axes of the identity covariance from :meth:`TruthBases.identity_principal_axes`),
  never raw coefficients.

The eye centres define the face frame (origin midway between them, x along them), so identity
moves them only symmetrically along x and expressions do not move them at all: the face frame of
every synthetic face is the one stated in :mod:`face_tracking_ros.model.topology`.

Presets:
    'default': four identity modes (face width, depth, nose projection, eye spacing) of 4.5, 3.0,
        1.75 and 1.25 mm RMS per node at one std on the 34 nodes, made orthogonal to the
        expression span on both the 34- and the 19-node mesh: a world whose identity and
        expression are well separated (the seed's assumption). Expression displacements at full
        intensity: jaw drop 18 mm, mouth corners 14 mm.
    'realistic': issue 11's world. Thirteen identity modes led by overall face size whose
        spectrum at the 19 seed nodes (square roots of the covariance eigenvalues, i.e. the norm
        over the 57 coordinates of each mode at one std) is the issue's 12.6, 9.0, 5.8, 4.6,
        3.7, 3.1, 2.4, 2.4, 2.0 and 1.2 mm, then 0.6, 0.5 and 0.4 mm for jaw width, cheek
        fullness and chin projection, which lie mostly outside those nodes (on all 34 nodes:
        21.9, 16.8, 12.5, 5.3, 5.1, ... mm). The fields share directions with the expressions
        (brow height and brow raise, face length and jaw opening, mouth width and smile or
        pucker): about 70 % of the expression span lies in the identity span at 19 nodes, 50 % at
        34. One std of face size scales the face by 5 %; over 3000 drawn faces the brow-to-chin
        height varies by 5.8 % (std), the mouth width by 10 %. Expressions are the default's
        scaled by 0.677 (jaw drop 12 mm, mouth corners 9.4 mm), so that their leading mode at 19
        nodes (intensities of std 0.5, as in :mod:`~face_tracking_ros.synthetic.true_model`) is
        the issue's 14.3 mm: 14.3, 11.0, 9.1, 4.8, 2.8 and 1.0 mm against the issue's 14.3, 8.2,
        3.6, 2.9, 1.3 and 0.7 (six named expressions of independent intensity cannot give its
        steeper tail).

The default's figures are half of those first chosen for it: at full scale its first mode changed
the width of a face by about 25 % per standard deviation.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np
from scipy.linalg import solve_triangular
from scipy.stats import truncnorm

from face_tracking_ros.errors import ConfigError
from face_tracking_ros.model.topology import mesh_topology
from face_tracking_ros.wording import listed

EXPRESSIONS = ('neutral', 'smile', 'jaw_open', 'brow_raise', 'frown', 'pucker', 'surprise')
"""Expression labels; index 0 is neutral (no displacement), the others have one basis column."""

ACTIVE_EXPRESSIONS = EXPRESSIONS[1:]
"""The named non-neutral expressions, in the column order of ``expression_basis_true``."""

PRESETS = ('default', 'realistic')

NUM_NODES = 34
# sigma_true is a normal truncated at +-2 of its own std (no caricatures), rescaled so that its
# variance is the preset's.
_TRUNCATION = 2.0
_TRUNCATED_VARIANCE = float(truncnorm.var(-_TRUNCATION, _TRUNCATION))
_EYE_CENTRES = ('right_eye', 'left_eye')

# A field maps the (N, 3) reference nodes in millimetres to an (N, 3) displacement direction.
Field = Callable[[np.ndarray], np.ndarray]


def _bump(
    points: np.ndarray, x: float, y: float, radius: float, mirror: bool = True
) -> np.ndarray:
    """Smooth (N,) bump exp(-d^2 / 2 radius^2) about (x, y) in mm, mirrored to (-x, y) if asked."""
    px = np.abs(points[:, 0]) if mirror else points[:, 0]
    return np.exp(-((px - x) ** 2 + (points[:, 1] - y) ** 2) / (2.0 * radius**2))


def _field(dx: np.ndarray | float, dy: np.ndarray | float, dz: np.ndarray | float) -> np.ndarray:
    """Stack per-node components (arrays or scalars broadcast to them) into an (N, 3) field."""
    return np.stack(np.broadcast_arrays(dx, dy, dz), axis=1).astype(float)


def _lateral(points: np.ndarray) -> np.ndarray:
    """(N,) sign of x: +1 on the subject's left, -1 on the right, 0 on the midline."""
    return np.sign(np.round(points[:, 0], 6))


# Identity deformation fields, in mm of the reference face (topology: y down, z into the head).
IDENTITY_FIELDS: dict[str, Field] = {
    'face_size': lambda p: _field(p[:, 0], p[:, 1], p[:, 2]),
    'face_width': lambda p: _field(p[:, 0], 0.0, 0.0),
    'face_length': lambda p: _field(0.0, np.where(p[:, 1] > 0, p[:, 1], 0.3 * p[:, 1]), 0.0),
    'face_depth': lambda p: _field(0.0, 0.0, p[:, 2]),
    'nose_projection': lambda p: _field(0.0, 0.0, -_bump(p, 0.0, 38.0, 12.0)),
    'jaw_width': lambda p: _field(p[:, 0] * np.clip((p[:, 1] - 40.0) / 60.0, 0.0, 1.0), 0.0, 0.0),
    'brow_height': lambda p: _field(0.0, -np.exp(-((p[:, 1] + 19.0) ** 2) / 128.0), 0.0),
    'eye_spacing': lambda p: _field(_lateral(p) * _bump(p, 31.0, 0.0, 16.0), 0.0, 0.0),
    'lip_fullness': lambda p: _field(
        0.0, np.sign(p[:, 1] - 70.0) * _bump(p, 0.0, 70.0, 14.0), -_bump(p, 0.0, 70.0, 14.0)
    ),
    'mouth_width': lambda p: _field(p[:, 0] * _bump(p, 0.0, 70.0, 18.0) / 25.0, 0.0, 0.0),
    'chin_projection': lambda p: _field(
        0.0, 0.3 * _bump(p, 0.0, 110.0, 18.0), -_bump(p, 0, 110, 18)
    ),
    'cheek_fullness': lambda p: _field(
        _lateral(p) * _bump(p, 60.0, 40.0, 20.0), 0.0, -0.5 * _bump(p, 60.0, 40.0, 20.0)
    ),
    'nose_deviation': lambda p: _field(_bump(p, 0.0, 45.0, 16.0, mirror=False), 0.0, 0.0),
}


@dataclass(frozen=True)
class _Preset:
    """How a preset builds its identity modes and scales its expressions.

    Attributes:
        modes: (field name, standard deviation of the mode in mm), in Gram-Schmidt order.
        nodes: mesh (34 or 19 nodes) on which the fields are orthonormalised; there the principal
            axes of the identity covariance are the modes themselves.
        per_node: the figures are RMS node displacements at one standard deviation (True), or
            the norm over all 3N coordinates of that mesh (False: the square roots of the
            covariance eigenvalues, the usual "spectrum" of a face model).
        separated: identity made orthogonal to the expression span first.
        expression_scale: factor on the full-intensity expression displacements.
    """

    modes: tuple[tuple[str, float], ...]
    nodes: int
    per_node: bool
    separated: bool
    expression_scale: float


_PRESETS: dict[str, _Preset] = {
    'default': _Preset(
        modes=(
            ('face_width', 4.5),
            ('face_depth', 3.0),
            ('nose_projection', 1.75),
            ('eye_spacing', 1.25),
        ),
        nodes=NUM_NODES,
        per_node=True,
        separated=True,
        expression_scale=1.0,
    ),
    'realistic': _Preset(
        modes=(
            ('face_size', 12.6),
            ('face_width', 9.0),
            ('face_length', 5.8),
            ('face_depth', 4.6),
            ('nose_projection', 3.7),
            ('brow_height', 3.1),
            ('eye_spacing', 2.4),
            ('lip_fullness', 2.4),
            ('mouth_width', 2.0),
            ('nose_deviation', 1.2),
            ('jaw_width', 0.6),
            ('cheek_fullness', 0.5),
            ('chin_projection', 0.4),
        ),
        nodes=19,
        per_node=False,
        separated=False,
        expression_scale=0.677,
    ),
}

# Per-node expression displacements at full intensity before the preset's scale, mm:
# {node name: (dx, dy, dz)} on the subject's right side and the midline; left-side nodes mirror x.
# Mouth corners move up, back and out in a smile; the lower lip, chin and jaw drop when the jaw
# opens; and so on.
_EXPRESSION_NODE_MOTION: dict[str, dict[str, tuple[float, float, float]]] = {
    'smile': {
        'mouth_right': (-8.0, -9.0, 7.0),
        'upper_lip_right': (-4.0, -3.0, 1.5),
        'upper_lip': (0.0, -2.0, 0.5),
        'lower_lip_right': (-4.5, -2.0, 1.5),
        'lower_lip': (0.0, -1.0, 0.5),
        'nose_right': (-2.0, -1.5, 0.0),
        'right_cheek_lower': (-3.0, -4.5, -3.0),
        'right_cheek_upper': (-1.0, -2.0, -1.5),
        'right_eye_outer': (0.0, -1.0, 0.0),
        'right_jaw': (-1.5, -1.5, 0.0),
    },
    'jaw_open': {
        'lower_lip': (0.0, 17.0, 4.0),
        'lower_lip_right': (1.5, 15.0, 3.5),
        'mouth_right': (2.5, 6.0, 1.5),
        'upper_lip': (0.0, -1.5, 0.0),
        'upper_lip_right': (0.0, -1.0, 0.0),
        'chin': (0.0, 18.0, 6.0),
        'right_chin': (1.0, 16.0, 5.0),
        'right_jaw': (1.5, 10.0, 3.0),
        'right_cheek_lower': (1.0, 4.0, 1.0),
    },
    'brow_raise': {
        'right_brow_inner': (0.0, -8.0, -1.5),
        'right_brow_middle': (0.0, -9.0, -1.5),
        'right_brow_outer': (0.0, -7.0, -1.0),
        'right_temple': (0.0, -1.5, 0.0),
    },
    'frown': {
        'right_brow_inner': (4.0, 6.0, -1.5),
        'right_brow_middle': (2.0, 4.0, -0.5),
        'right_brow_outer': (0.0, 1.5, 0.0),
        'right_eye_inner': (0.5, 0.5, 0.0),
        'mouth_right': (0.0, 3.0, 0.0),
        'lower_lip': (0.0, -1.5, -1.0),
    },
    'pucker': {
        'mouth_right': (10.0, -0.5, -6.0),
        'upper_lip_right': (4.5, 0.5, -8.0),
        'upper_lip': (0.0, 1.0, -10.0),
        'lower_lip_right': (4.5, -0.5, -8.0),
        'lower_lip': (0.0, -1.5, -10.0),
        'right_cheek_lower': (2.0, 0.0, 1.0),
        'right_chin': (0.5, -0.5, -1.0),
        'chin': (0.0, -0.5, -2.0),
    },
    'surprise': {
        'right_brow_inner': (-0.5, -10.0, -1.5),
        'right_brow_middle': (0.0, -11.0, -1.5),
        'right_brow_outer': (0.0, -8.0, -1.0),
        'right_eye_outer': (0.0, -0.5, 0.0),
        'lower_lip': (0.0, 12.0, 3.0),
        'lower_lip_right': (2.0, 10.0, 3.0),
        'mouth_right': (5.0, 3.5, 0.0),
        'upper_lip': (0.0, -3.0, -1.5),
        'upper_lip_right': (1.0, -2.0, -1.0),
        'chin': (0.0, 12.0, 4.0),
        'right_chin': (1.0, 11.0, 3.5),
        'right_jaw': (1.0, 7.0, 2.0),
    },
}

_RIGHT, _LEFT = 'right', 'left'


@dataclass(frozen=True)
class Subject:
    """One synthetic subject of a population.

    Attributes:
        subject_id: identifier, e.g. 'subject_03'.
        index: position in the population (seeds the subject's appearance too).
        sigma_true: (K,) true identity coefficients in ``identity_basis_true``, metres.
        neutral_nodes: (34, 3) neutral face in the face frame, metres.
        appearance_seed: seed of the subject's skin, eye and hair texture.
    """

    subject_id: str
    index: int
    sigma_true: np.ndarray
    neutral_nodes: np.ndarray
    appearance_seed: int


@dataclass(frozen=True)
class TruthBases:
    """The true model of a population restricted to an N-node mesh (eq. 3 with true bases).

    Attributes:
        node_names: N node names.
        mean_shape: (3N,) population mean face (the reference face), metres.
        identity_basis: (3N, K) identity directions; orthonormal columns only on the preset's
            mesh (34 nodes for 'default', 19 for 'realistic').
        identity_variances: (K,) variances of sigma_true, m^2.
        expression_basis: (3N, E) full-intensity displacement of each active expression, metres,
            in the order of :data:`ACTIVE_EXPRESSIONS`.
    """

    node_names: tuple[str, ...]
    mean_shape: np.ndarray
    identity_basis: np.ndarray
    identity_variances: np.ndarray
    expression_basis: np.ndarray

    @property
    def num_nodes(self) -> int:
        """Number of nodes N."""
        return len(self.node_names)

    def identity_principal_axes(self) -> tuple[np.ndarray, np.ndarray]:
        """Principal axes of the identity covariance B diag(var) B^T at these nodes.

        Returns:
            ``(axes, variances)``: (3N, K) orthonormal axes by decreasing variance and their (K,)
            variances in m^2. The true top-p identity subspace is ``axes[:, :p]``.
        """
        scaled = self.identity_basis * np.sqrt(self.identity_variances)
        axes, singular, _ = np.linalg.svd(scaled, full_matrices=False)
        return axes, singular**2

    def expression_span(self) -> np.ndarray:
        """(3N, E) orthonormal basis of the span of the expression displacements."""
        axes, _, _ = np.linalg.svd(self.expression_basis, full_matrices=False)
        return axes

    def identity_rms_mm(self) -> np.ndarray:
        """(K,) RMS node displacement of each principal identity axis at one std, mm."""
        _, variances = self.identity_principal_axes()
        return 1000.0 * np.sqrt(variances / self.num_nodes)


class FacePopulation:
    """A deterministic population of synthetic subjects with true identity and expression bases.

    Args:
        preset: 'default' (four well-separated identity modes) or 'realistic' (thirteen modes
            with issue 11's slowly decaying spectrum, partly shared with expressions).
        seed: seed of every subject's sigma_true and appearance; subject i does not depend on how
            many subjects are drawn.

    Raises:
        ConfigError: for an unknown preset or a negative seed.
    """

    def __init__(self, preset: str = 'default', seed: int = 0) -> None:
        """Build the true bases of the preset."""
        if preset not in PRESETS:
            msg = f'unknown population preset {preset!r}; choose one of {PRESETS}'
            raise ConfigError(msg)
        if seed < 0:
            msg = f'population seed must be >= 0, got {seed}'
            raise ConfigError(msg)
        self.preset = preset
        self.seed = seed
        self._topology = mesh_topology(NUM_NODES)
        reference_mm = 1000.0 * self._topology.reference_shape
        spec = _PRESETS[preset]
        self.expression_basis_true = spec.expression_scale * np.stack(
            [_expression_field(name) / 1000.0 for name in ACTIVE_EXPRESSIONS], axis=1
        )
        fields = np.stack(
            [
                self._pin_eye_centres(IDENTITY_FIELDS[name](reference_mm)).ravel()
                for name, _ in spec.modes
            ],
            axis=1,
        )
        if spec.separated:
            fields = _orthogonal_to_expressions(fields, self.expression_basis_true)
        self.identity_basis_true = _gram_schmidt(fields, 3 * spec.nodes)
        std_m = np.array([std for _, std in spec.modes]) / 1000.0
        self.identity_variances_true = (spec.nodes if spec.per_node else 1) * std_m**2
        self.identity_mode_names = tuple(name for name, _ in spec.modes)
        self.mean_shape = self._topology.reference_shape.ravel().copy()
        for array in (self.identity_basis_true, self.identity_variances_true, self.mean_shape):
            array.setflags(write=False)
        self.expression_basis_true.setflags(write=False)

    @property
    def num_identity_modes(self) -> int:
        """Number K of true identity modes."""
        return int(self.identity_basis_true.shape[1])

    @property
    def node_names(self) -> tuple[str, ...]:
        """The 34 node names."""
        return self._topology.node_names

    def subject(self, index: int) -> Subject:
        """Subject ``index`` (>= 0): its sigma_true and neutral 34-node face.

        Raises:
            ConfigError: for a negative index.
        """
        if index < 0:
            msg = f'subject index must be >= 0, got {index}'
            raise ConfigError(msg)
        rng = np.random.default_rng([self.seed, index])
        standard = truncnorm.rvs(
            -_TRUNCATION, _TRUNCATION, size=self.num_identity_modes, random_state=rng
        )
        sigma_true = standard * np.sqrt(self.identity_variances_true / _TRUNCATED_VARIANCE)
        neutral = (self.mean_shape + self.identity_basis_true @ sigma_true).reshape(NUM_NODES, 3)
        return Subject(
            subject_id=f'subject_{index:02d}',
            index=index,
            sigma_true=sigma_true,
            neutral_nodes=neutral,
            appearance_seed=int(rng.integers(0, 2**31 - 1)),
        )

    def alpha(self, weights: Mapping[str, float] | np.ndarray) -> np.ndarray:
        """The (E,) alpha_true of expression weights given by name or as an (E,) array.

        Raises:
            ConfigError: for an unknown expression name or an array of the wrong shape.
        """
        if isinstance(weights, Mapping):
            unknown = sorted(set(weights) - set(EXPRESSIONS))
            if unknown:
                msg = f'unknown {listed("expression", unknown)}; known: {", ".join(EXPRESSIONS)}'
                raise ConfigError(msg)
            return np.array([float(weights.get(name, 0.0)) for name in ACTIVE_EXPRESSIONS])
        alpha = np.asarray(weights, dtype=float)
        if alpha.shape != (len(ACTIVE_EXPRESSIONS),):
            count = len(ACTIVE_EXPRESSIONS)
            msg = f'expression weights must have shape ({count},), got {alpha.shape}'
            raise ConfigError(msg)
        return alpha

    def expression_displacement(self, weights: Mapping[str, float] | np.ndarray) -> np.ndarray:
        """(34, 3) displacement (m) of expression weights (names or an (E,) alpha_true)."""
        return (self.expression_basis_true @ self.alpha(weights)).reshape(NUM_NODES, 3)

    def nodes(self, subject: Subject, weights: Mapping[str, float] | np.ndarray) -> np.ndarray:
        """Eq. 3 with true bases: the (34, 3) face-frame nodes (m) of a subject's expression."""
        return subject.neutral_nodes + self.expression_displacement(weights)

    def truth(self, num_nodes: int = NUM_NODES) -> TruthBases:
        """The true model restricted to the first ``num_nodes`` nodes (19 or 34).

        Raises:
            ConfigError: for another node count.
        """
        names = mesh_topology(num_nodes).node_names
        rows = slice(0, 3 * num_nodes)
        return TruthBases(
            node_names=names,
            mean_shape=self.mean_shape[rows],
            identity_basis=self.identity_basis_true[rows],
            identity_variances=self.identity_variances_true,
            expression_basis=self.expression_basis_true[rows],
        )

    def _pin_eye_centres(self, field: np.ndarray) -> np.ndarray:
        """Keep the face frame: eye centres move only apart or together along x, symmetrically."""
        pinned = field.copy()
        right, left = (self._topology.index(name) for name in _EYE_CENTRES)
        spread = 0.5 * (pinned[left, 0] - pinned[right, 0])
        pinned[[right, left]] = [[-spread, 0.0, 0.0], [spread, 0.0, 0.0]]
        return pinned


def _gram_schmidt(fields: np.ndarray, rows: int) -> np.ndarray:
    """Gram-Schmidt of (102, K) fields on their first ``rows`` coordinates, carried to all.

    Returns the combinations of the fields, in their order, whose first ``rows`` coordinates are
    orthonormal (each column keeps the sign of its own field); the other coordinates follow the
    same combinations, so every column is a smooth deformation of the whole face.
    """
    basis, triangular = np.linalg.qr(fields[:rows])
    signs = np.sign(np.diag(triangular))
    carried = solve_triangular(signs[:, None] * triangular, fields[rows:].T, trans='T').T
    return np.vstack([basis * signs, carried])


def _orthogonal_to_expressions(fields: np.ndarray, expressions: np.ndarray) -> np.ndarray:
    """Remove from (102, K) fields the expression span at 34 nodes and at the 19-node subset.

    After this, identity and expression are orthogonal on both meshes of the package.
    """
    padded_19 = np.zeros_like(expressions)
    padded_19[: 3 * 19] = expressions[: 3 * 19]
    span = np.linalg.svd(np.hstack([expressions, padded_19]), full_matrices=False)[0]
    return fields - span @ (span.T @ fields)


def _expression_field(expression: str) -> np.ndarray:
    """(102,) full-intensity displacement of an expression, mm, mirrored to the subject's left."""
    topology = mesh_topology(NUM_NODES)
    field = np.zeros((NUM_NODES, 3))
    for name, (dx, dy, dz) in _EXPRESSION_NODE_MOTION[expression].items():
        field[topology.index(name)] = (dx, dy, dz)
        if _RIGHT in name:
            field[topology.index(name.replace(_RIGHT, _LEFT))] = (-dx, dy, dz)
    return field.ravel()
