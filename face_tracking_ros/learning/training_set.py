"""Training data for model learning (§3.3, §3.4): 3-D meshes with subject, neutral flag and label.

Frames of all subjects are stored flat, with per-frame index arrays, so the learners work on one
``(F, N, 3)`` stack. A :class:`MeshSequence` is one recorded sequence of one subject (one bag);
:meth:`TrainingSet.from_sequences` pools sequences, merging those of the same subject.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np
import scipy.sparse

from face_tracking_ros.errors import InputError
from face_tracking_ros.model.topology import SUPPORTED_NODE_COUNTS
from face_tracking_ros.wording import counted

NEUTRAL_LABEL = 'neutral'


@dataclass(frozen=True)
class MeshSequence:
    """One sequence of meshes of one subject.

    Attributes:
        subject_id: the subject's identifier.
        meshes: (F, N, 3) node positions, metres, in any rigid frame (camera or face).
        neutral: (F,) bool, frames labelled neutral (the §3.4 'neutral expression meshes').
        labels: F expression labels, or None when unknown.
        source: where the sequence came from (bag path), for error messages.
    """

    subject_id: str
    meshes: np.ndarray
    neutral: np.ndarray
    labels: tuple[str, ...] | None = None
    source: str = ''

    @classmethod
    def labelled(
        cls, subject_id: str, meshes: np.ndarray, labels: tuple[str, ...], source: str = ''
    ) -> MeshSequence:
        """A sequence with expression labels; the frames labelled neutral are its neutral set."""
        neutral = np.array([label == NEUTRAL_LABEL for label in labels])
        return cls(subject_id, meshes, neutral, labels, source)


@dataclass(frozen=True)
class TrainingSet:
    """Pooled training meshes of several subjects.

    Attributes:
        meshes: (F, N, 3) node positions of all frames, metres.
        subject_index: (F,) int index into ``subject_ids`` of each frame.
        neutral: (F,) bool, frames labelled neutral.
        subject_ids: the S subject identifiers, in order of first appearance.
        sequence_index: (F,) int, which sequence of its subject each frame comes from (0, 1, ...).
        labels: (F,) str expression labels, or None when unknown.
        subject_sources: per subject, where its frames came from (bag paths), for messages.
    """

    meshes: np.ndarray
    subject_index: np.ndarray
    neutral: np.ndarray
    subject_ids: tuple[str, ...]
    sequence_index: np.ndarray
    labels: np.ndarray | None = None
    subject_sources: tuple[str, ...] | None = None

    def __post_init__(self) -> None:
        """Validate the pooled arrays; errors name the subject at fault."""
        frames = self.meshes.shape[0]
        for name in ('subject_index', 'neutral', 'sequence_index'):
            if getattr(self, name).shape != (frames,):
                msg = f'{name} has shape {getattr(self, name).shape}, expected ({frames},)'
                raise InputError(msg)
        if self.labels is not None and self.labels.shape != (frames,):
            msg = f'labels has shape {self.labels.shape}, expected ({frames},)'
            raise InputError(msg)
        for s, subject in enumerate(self.subject_ids):
            mine = self.subject_index == s
            if not np.any(mine):
                msg = f'subject {subject!r} has no frames'
                raise InputError(msg)
            if not np.any(self.neutral[mine]):
                sources = f' ({self.subject_sources[s]})' if self.subject_sources else ''
                msg = f'subject {subject!r}{sources} has no neutral frames'
                raise InputError(msg)

    @classmethod
    def from_sequences(cls, sequences: Sequence[MeshSequence]) -> TrainingSet:
        """Pool sequences; sequences sharing a subject id belong to the same subject.

        Raises:
            InputError: naming the subject and source on an empty sequence, a node count other
                than 19 or 34 or different from the other sequences, NaN/Inf nodes, a neutral
                flag or label count that does not match the frames, or a subject without any
                neutral frame.
        """
        if not sequences:
            msg = 'no training sequences given'
            raise InputError(msg)
        node_counts = {_check_sequence(sequence) for sequence in sequences}
        if len(node_counts) > 1:
            counts = ', '.join(f'{_where(s)}: {s.meshes.shape[1]}' for s in sequences)
            msg = f'sequences have different node counts ({counts})'
            raise InputError(msg)
        subject_ids = tuple(dict.fromkeys(sequence.subject_id for sequence in sequences))
        seen: dict[str, int] = dict.fromkeys(subject_ids, 0)
        sequence_index = []
        for sequence in sequences:
            sequence_index.append(np.full(len(sequence.meshes), seen[sequence.subject_id]))
            seen[sequence.subject_id] += 1
        has_labels = all(sequence.labels is not None for sequence in sequences)
        return cls(
            meshes=np.concatenate([np.asarray(s.meshes, dtype=float) for s in sequences]),
            subject_index=np.concatenate(
                [np.full(len(s.meshes), subject_ids.index(s.subject_id)) for s in sequences]
            ),
            neutral=np.concatenate([np.asarray(s.neutral, dtype=bool) for s in sequences]),
            subject_ids=subject_ids,
            sequence_index=np.concatenate(sequence_index),
            labels=np.concatenate([np.asarray(s.labels, dtype=str) for s in sequences])
            if has_labels
            else None,
            subject_sources=tuple(
                ', '.join(s.source for s in sequences if s.subject_id == subject and s.source)
                for subject in subject_ids
            ),
        )

    @property
    def num_subjects(self) -> int:
        """Number of subjects S."""
        return len(self.subject_ids)

    @property
    def num_nodes(self) -> int:
        """Number of mesh nodes N."""
        return int(self.meshes.shape[1])

    def flat(self) -> np.ndarray:
        """(F, 3N) meshes flattened node-major, as the model's vectors (eq. 3)."""
        return self.meshes.reshape(len(self.meshes), -1)

    def subject_means(self, values: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
        """Per-subject means of per-frame values, each subject weighted equally within itself.

        Args:
            values: (F, D) per-frame values.
            mask: (F,) bool frames to use (e.g. the neutral ones); None for all frames.

        Returns:
            (S, D) mean of each subject's (masked) frames.
        """
        membership = self._membership if mask is None else self._membership.multiply(mask)
        return np.asarray(membership @ values) / membership.sum(axis=1)[:, None]

    @cached_property
    def sequence_of_frame(self) -> np.ndarray:
        """(F,) index 0 .. K - 1 of each frame's recorded sequence, a (subject, sequence) pair."""
        pairs = np.stack([self.subject_index, self.sequence_index], axis=1)
        _, index = np.unique(pairs, axis=0, return_inverse=True)
        return index.ravel()

    @cached_property
    def sequence_subject(self) -> np.ndarray:
        """(K,) subject index of each sequence of :attr:`sequence_of_frame`."""
        subject = np.empty(int(self.sequence_of_frame.max()) + 1, dtype=self.subject_index.dtype)
        subject[self.sequence_of_frame] = self.subject_index
        return subject

    def sequence_means(self, values: np.ndarray) -> np.ndarray:
        """(K, D) mean of per-frame values (F, D) over each sequence, :attr:`sequence_of_frame`."""
        membership = self._sequence_membership
        return np.asarray(membership @ values) / membership.sum(axis=1)[:, None]

    def sequence_sums(self, values: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per-sequence sums of per-frame values over the frames in a mask.

        Args:
            values: (F, D) per-frame values.
            mask: (F,) bool frames to use.

        Returns:
            (K, D) sums over each sequence's masked frames, and (K,) how many frames each has.
        """
        membership = self._sequence_membership.multiply(mask)
        return np.asarray(membership @ values), np.asarray(membership.sum(axis=1)).ravel()

    @cached_property
    def _membership(self) -> scipy.sparse.csr_array:
        """(S, F) sparse 0/1 matrix: frame f belongs to subject s."""
        return _membership(self.subject_index, self.num_subjects)

    @cached_property
    def _sequence_membership(self) -> scipy.sparse.csr_array:
        """(K, F) sparse 0/1 matrix: frame f belongs to sequence k."""
        return _membership(self.sequence_of_frame, int(self.sequence_of_frame.max()) + 1)

    def without_subject(self, subject: int) -> TrainingSet:
        """The training set with one subject (by index) left out, for leave-one-out tests."""
        keep = self.subject_index != subject
        index = self.subject_index[keep]
        return replace(
            self,
            meshes=self.meshes[keep],
            subject_index=np.where(index > subject, index - 1, index),
            neutral=self.neutral[keep],
            subject_ids=_drop(self.subject_ids, subject),
            sequence_index=self.sequence_index[keep],
            labels=None if self.labels is None else self.labels[keep],
            subject_sources=None
            if self.subject_sources is None
            else _drop(self.subject_sources, subject),
        )

    def with_meshes(self, meshes: np.ndarray) -> TrainingSet:
        """The same frames with other node positions (e.g. after alignment)."""
        return replace(self, meshes=meshes)


def _membership(index: np.ndarray, groups: int) -> scipy.sparse.csr_array:
    """(G, F) sparse 0/1 matrix: frame f belongs to group ``index[f]``."""
    frames = len(index)
    return scipy.sparse.csr_array(
        (np.ones(frames), (index, np.arange(frames))), shape=(groups, frames)
    )


def _drop(items: tuple[str, ...], index: int) -> tuple[str, ...]:
    """The tuple without entry ``index``."""
    return items[:index] + items[index + 1 :]


def _where(sequence: MeshSequence) -> str:
    """'subject 'x' (source)' for error messages."""
    return f'subject {sequence.subject_id!r}' + (
        f' ({sequence.source})' if sequence.source else ''
    )


def _check_sequence(sequence: MeshSequence) -> int:
    """Validate one sequence and return its node count."""
    where = _where(sequence)
    meshes = np.asarray(sequence.meshes)
    if meshes.ndim != 3 or meshes.shape[-1] != 3 or meshes.shape[0] == 0:
        msg = f'{where}: meshes must be a non-empty (F, N, 3) stack, got shape {meshes.shape}'
        raise InputError(msg)
    if meshes.shape[1] not in SUPPORTED_NODE_COUNTS:
        msg = f'{where}: meshes have {meshes.shape[1]} nodes; supported: {SUPPORTED_NODE_COUNTS}'
        raise InputError(msg)
    bad = ~np.all(np.isfinite(meshes), axis=(1, 2))
    if np.any(bad):
        msg = (
            f'{where}: {counted(int(bad.sum()), "mesh", "meshes")} hold NaN or Inf, first at '
            f'frame {np.argmax(bad)}'
        )
        raise InputError(msg)
    if np.shape(sequence.neutral) != (len(meshes),):
        flags = counted(np.size(sequence.neutral), 'neutral flag')
        msg = f'{where}: {flags} for {counted(len(meshes), "frame")}'
        raise InputError(msg)
    if sequence.labels is not None and len(sequence.labels) != len(meshes):
        labels = counted(len(sequence.labels), 'label')
        msg = f'{where}: {labels} for {counted(len(meshes), "frame")}'
        raise InputError(msg)
    return int(meshes.shape[1])
