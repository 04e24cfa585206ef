"""What a replay's output bag was made from, recorded in its rosbag2 metadata (``custom_data``).

Every output bag of :func:`~face_tracking_ros.replay.replay_bag` (``face-tracking track``,
``replay``, and the stereo tracking of raw bags in ``learn``) records its input bag, the nodes,
their parameters, with a digest of each file a parameter names (an init file edited in place is
another input), the remappings, and whether the replay reached the end of its input. ``learn``
uses it to re-use meshes that an earlier run tracked from the same inputs, and to check that
``--truth`` pairs each mesh bag with the bag it was tracked from.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
import hashlib
import json
from pathlib import Path
from typing import Any

from face_tracking_ros.data import default_model_path
from face_tracking_ros.errors import ConfigError
from face_tracking_ros.io.bags import custom_data

KEY = 'face_tracking_ros.replay'
MONO, STEREO = 'mono_tracker', 'stereo_tracker'
MODEL_PARAMETER = 'model_file'


@dataclass(frozen=True)
class Provenance:
    """The inputs of one replay.

    Attributes:
        source: the input bag, as an absolute path.
        nodes: the nodes replayed.
        parameters: their parameters, name -> value text.
        file_digests: parameter name -> SHA-256 of the file its value names, for every parameter
            naming an existing file.
        remaps: processor input topic -> bag topic.
        complete: the replay read its input to the end (not interrupted, no damage).
    """

    source: str
    nodes: tuple[str, ...]
    parameters: dict[str, str]
    file_digests: dict[str, str]
    remaps: dict[str, str] = field(default_factory=dict)
    complete: bool = True

    @classmethod
    def of(
        cls,
        bag: Path,
        nodes: Sequence[str],
        parameters: Mapping[str, str],
        remaps: Mapping[str, str] | None = None,
    ) -> Provenance:
        """The provenance of a replay of ``bag`` about to start (complete until said otherwise)."""
        digests = {
            name: file_digest(Path(value))
            for name, value in parameters.items()
            if value and Path(value).is_file()
        }
        return cls(
            source=replay_source(bag),
            nodes=tuple(nodes),
            parameters=dict(sorted(parameters.items())),
            file_digests=dict(sorted(digests.items())),
            remaps=dict(sorted((remaps or {}).items())),
        )

    @classmethod
    def read(cls, bag: Path) -> Provenance | None:
        """The provenance a bag records; None if it records none (or is unreadable)."""
        text = custom_data(bag).get(KEY)
        if text is None:
            return None
        try:
            fields: dict[str, Any] = json.loads(text)
            return cls(**{**fields, 'nodes': tuple(fields['nodes'])})
        except (ValueError, TypeError, KeyError):
            return None

    def tracking_model(self) -> tuple[str, str | None] | None:
        """The tracker's ``model_file`` ('' for the mono tracker's default) and its SHA-256.

        None if no tracker with a model was replayed (a stereo_tracker without ``model_file``
        tracks meshes only); the digest is None where the file was not found.
        """
        value = self.parameters.get(MODEL_PARAMETER, '')
        if MONO not in self.nodes and not (STEREO in self.nodes and value):
            return None
        return value, self.file_digests.get(MODEL_PARAMETER)

    def same_inputs(self, other: Provenance) -> bool:
        """Whether ``other`` replayed the same bag through the same nodes, set up the same way."""
        return replace(self, complete=True) == replace(other, complete=True)

    def text(self) -> str:
        """The JSON text recorded under :data:`KEY`."""
        return json.dumps(asdict(self), sort_keys=True)


def replay_source(bag: Path) -> str:
    """The input bag as its replay records it (:attr:`Provenance.source`): absolute, resolved."""
    return str(bag.resolve())


def file_digest(path: Path) -> str:
    """The SHA-256 of a file's bytes, as recorded in :attr:`Provenance.file_digests`."""
    return hashlib.sha256(path.read_bytes()).hexdigest()


def other_source(made: Path, source: Path) -> str | None:
    """The bag ``made`` records it was replayed from, if that is not ``source``.

    Compared as files when the recorded one is still there (a link to it is the same bag, a bag
    of the same name in another directory is not), else by name (the bags may have moved
    since); None if it is the same, or ``made`` records none.
    """
    provenance = Provenance.read(made)
    if provenance is None:
        return None
    recorded = Path(provenance.source)
    same = (
        recorded.resolve() == source.resolve()
        if recorded.exists()
        else recorded.name == source.name
    )
    return None if same else provenance.source


def tracked_with(bags: Sequence[Path], given: Path | None) -> Path | None:
    """The face model file tracker output bags were made with, as far as they say.

    Args:
        bags: tracker output bags; those that record a tracker's replay name its model.
        given: the model the user says they were tracked with; None: not said.

    Returns:
        ``given`` if no bag says otherwise, else the model the bags name (the packaged default
        for a tracker run without ``model_file``), None if neither.

    Raises:
        ConfigError: if a bag was tracked with another model than ``given``, the bags with
            different models, or with a model file that is gone or has changed since.
    """
    recorded = {}
    for bag in bags:
        provenance = Provenance.read(bag)
        used = provenance.tracking_model() if provenance is not None else None
        if used is not None:
            value, digest = used
            path = Path(value) if value else default_model_path()
            recorded[bag] = (path, digest or _digest_now(path))
    if given is not None and given.is_file():  # (a missing one is for its loader to name)
        wanted = file_digest(given)
        for bag, (path, digest) in recorded.items():
            if digest != wanted:
                msg = f'{bag} was tracked with the face model {path}, not {given}'
                raise ConfigError(f'{msg}: give that model')
        return given
    models = {digest: path for path, digest in recorded.values()}
    if given is not None or not models:
        return given
    if len(models) > 1:
        names = ', '.join(sorted(map(str, models.values())))
        msg = f'the bags were tracked with different face models ({names}): give those of one'
        raise ConfigError(msg)
    bag, (path, digest) = next(iter(recorded.items()))
    if digest is None or _digest_now(path) != digest:
        msg = f'{bag} was tracked with the face model {path}, which is gone or has changed since'
        raise ConfigError(f'{msg}: give that model as --model')
    return path


def _digest_now(path: Path) -> str | None:
    """The SHA-256 of the file at ``path`` now; None if there is none."""
    return file_digest(path) if path.is_file() else None
