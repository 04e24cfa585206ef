"""Head-pose trajectories and expression time courses of the synthetic sequences.

Both are continuous functions of time (seconds), so frames and motion-blur sub-samples are
evaluated at exact instants and a sequence does not depend on its frame rate's rounding.

Head motion (eq. 1's omega(t) and t(t)) is a sum of a few random sinusoids per degree of freedom
(0.05 to 0.4 Hz), bounded by construction: the sum of the amplitudes never exceeds the range.

- 'free' (test sequences): yaw within +-35 deg, pitch +-25 deg, roll +-20 deg, the face-frame
  origin within a 15 cm cube whose centre is 57.5 to 72.5 cm from the camera (so every position
  is 50 to 80 cm away). Peak angular speeds are tens of degrees per second, as in conversation.
- 'still' (training sequences, the seed's §3.3 protocol): the head is meant to stay still; a slow
  residual sway of at most 0.8 deg per axis and 3 mm per axis remains.
- 'static' (jitter measurements): head, expression and light held fixed; from frame to frame
  only the sensor noise changes.

Expression scripts give, per instant, the expression being played (its label, 'neutral' between
expressions), its intensity in [0, 1] (raised-cosine onset, apex, raised-cosine offset) and the
true alpha (:mod:`face_tracking_ros.synthetic.faces`: intensity on that expression's column).
Training scripts start with a neutral stretch and then play expressions in turn; test scripts
play random expressions at random times, with talking (an oscillating jaw) among them.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

import numpy as np

from face_tracking_ros.errors import ConfigError
from face_tracking_ros.geometry.rotation import angles_to_omega
from face_tracking_ros.synthetic.faces import ACTIVE_EXPRESSIONS

FREE_ANGLE_LIMITS = np.radians([25.0, 35.0, 20.0])  # pitch (x), yaw (y), roll (z)
FREE_HALF_SIZE = 0.075  # half edge of the working cube, m
NEAREST, FARTHEST = 0.50, 0.80  # range of distances of the face-frame origin, m
STILL_ANGLE_LIMIT = np.radians(0.8)
STILL_SHIFT_LIMIT = 0.003  # m
_COMPONENTS = 3
_FREQUENCIES = (0.05, 0.4)  # Hz
_STILL_FREQUENCIES = (0.05, 0.25)  # Hz, breathing-like sway
_TALK_HZ = 3.5  # syllable rate of the talking jaw


class Motion(StrEnum):
    """Kinds of head motion."""

    STILL = 'still'
    FREE = 'free'
    STATIC = 'static'


@dataclass(frozen=True)
class _Sinusoids:
    """A bounded sum of sinusoids per channel: x(t) = sum_k a_k sin(2 pi f_k t + phi_k)."""

    amplitude: np.ndarray  # (C, K)
    frequency: np.ndarray  # (C, K), Hz
    phase: np.ndarray  # (C, K), rad

    @classmethod
    def random(
        cls, rng: np.random.Generator, limits: np.ndarray, frequencies: tuple[float, float]
    ) -> _Sinusoids:
        """Random sinusoids whose amplitudes sum to 60-100 % of each channel's limit."""
        channels = len(limits)
        weights = rng.uniform(0.2, 1.0, (channels, _COMPONENTS))
        reach = limits[:, None] * rng.uniform(0.6, 1.0, (channels, 1))
        return cls(
            amplitude=reach * weights / weights.sum(axis=1, keepdims=True),
            frequency=rng.uniform(*frequencies, (channels, _COMPONENTS)),
            phase=rng.uniform(0.0, 2.0 * np.pi, (channels, _COMPONENTS)),
        )

    def __call__(self, time: float) -> np.ndarray:
        """(C,) values at ``time`` seconds."""
        return np.sum(self.amplitude * np.sin(2 * np.pi * self.frequency * time + self.phase), 1)


@dataclass(frozen=True)
class HeadTrajectory:
    """A smooth, bounded head-pose trajectory (eq. 1): omega(time) and t(time).

    Attributes:
        centre: (3,) mean position of the face-frame origin, camera frame, m.
        motion: 'still', 'free' or 'static'.
        angle_waves: pitch, yaw and roll about their zero, radians.
        shift_waves: offset of the face-frame origin from ``centre``, m.
    """

    centre: np.ndarray
    motion: Motion
    angle_waves: _Sinusoids
    shift_waves: _Sinusoids

    @classmethod
    def random(
        cls, motion: Motion | str, rng: np.random.Generator, lateral_offset: float = 0.0
    ) -> HeadTrajectory:
        """A random trajectory of the given kind.

        Args:
            motion: 'still', 'free' or 'static'.
            rng: randomness.
            lateral_offset: x of the working volume's centre, m (half the baseline for a
                stereo rig, so both cameras see the face).

        Raises:
            ConfigError: for an unknown motion kind.
        """
        try:
            motion = Motion(motion)
        except ValueError:
            msg = f'unknown motion {motion!r}; choose one of {[m.value for m in Motion]}'
            raise ConfigError(msg) from None
        depth = rng.uniform(NEAREST + FREE_HALF_SIZE, FARTHEST - FREE_HALF_SIZE)
        centre = np.array(
            [lateral_offset + rng.uniform(-0.02, 0.02), rng.uniform(-0.01, 0.03), depth]
        )
        if motion is Motion.FREE:
            angles = _Sinusoids.random(rng, FREE_ANGLE_LIMITS, _FREQUENCIES)
            shift = _Sinusoids.random(rng, np.full(3, FREE_HALF_SIZE), _FREQUENCIES)
        else:
            scale = 0.0 if motion is Motion.STATIC else 1.0
            angles = _Sinusoids.random(
                rng, np.full(3, scale * STILL_ANGLE_LIMIT), _STILL_FREQUENCIES
            )
            shift = _Sinusoids.random(
                rng, np.full(3, scale * STILL_SHIFT_LIMIT), _STILL_FREQUENCIES
            )
        return cls(centre=centre, motion=motion, angle_waves=angles, shift_waves=shift)

    def angles(self, time: float) -> np.ndarray:
        """(3,) pitch, yaw, roll at ``time`` s (rotations about camera x, y, z), radians."""
        return self.angle_waves(time)

    def pose(self, time: float) -> tuple[np.ndarray, np.ndarray]:
        """``(omega, t)`` at ``time`` seconds: rotation vector (rad) and translation (m)."""
        return angles_to_omega(self.angles(time)), self.centre + self.shift_waves(time)


@dataclass(frozen=True)
class ExpressionSegment:
    """One expression played once: ramps up, holds, ramps down.

    Attributes:
        label: an expression of :data:`ACTIVE_EXPRESSIONS`.
        start: onset start, s.
        rise: onset duration, s.
        hold: apex duration, s.
        fall: offset duration, s.
        peak: apex intensity in (0, 1].
        talk: if True the intensity oscillates at a syllable rate during the apex (talking).
    """

    label: str
    start: float
    rise: float
    hold: float
    fall: float
    peak: float
    talk: bool = False

    @property
    def end(self) -> float:
        """Offset end, s."""
        return self.start + self.rise + self.hold + self.fall

    def intensity(self, time: float) -> float:
        """Intensity in [0, peak] at ``time`` s (0 outside the segment); continuous in time."""
        local = time - self.start
        if local <= 0.0 or time >= self.end:
            return 0.0
        if local < self.rise:
            return self.peak * 0.5 * (1.0 - np.cos(np.pi * local / self.rise))
        local -= self.rise
        if local < self.hold:
            return self._apex(local)
        local -= self.hold
        return self._apex(self.hold) * 0.5 * (1.0 + np.cos(np.pi * local / self.fall))

    def _apex(self, local: float) -> float:
        """Intensity ``local`` s into the apex: the peak, or a talking oscillation below it."""
        if not self.talk:
            return self.peak
        return self.peak * (0.65 + 0.35 * np.cos(2.0 * np.pi * _TALK_HZ * local))


@dataclass(frozen=True)
class ExpressionState:
    """The expression truth at one instant.

    Attributes:
        label: expression being played, 'neutral' between expressions.
        intensity: its intensity in [0, 1].
        alpha: (E,) true alpha, intensity on the label's column of the true expression basis.
    """

    label: str
    intensity: float
    alpha: np.ndarray


@dataclass(frozen=True)
class ExpressionScript:
    """Non-overlapping expression segments over a sequence.

    Attributes:
        segments: the segments, in time order.
    """

    segments: tuple[ExpressionSegment, ...]

    def state(self, time: float) -> ExpressionState:
        """The expression truth at ``time`` seconds."""
        alpha = np.zeros(len(ACTIVE_EXPRESSIONS))
        for segment in self.segments:
            if segment.start < time < segment.end:
                intensity = segment.intensity(time)
                alpha[ACTIVE_EXPRESSIONS.index(segment.label)] = intensity
                return ExpressionState(segment.label, intensity, alpha)
        return ExpressionState('neutral', 0.0, alpha)

    @classmethod
    def training(cls, duration: float, first: int = 0) -> ExpressionScript:
        """The seed's training protocol: neutral, then each expression in turn, neutral between.

        The first 20 % of the sequence (at least 0.5 s when there is room) is neutral; the rest
        is shared by as many expressions as fit at about 2 s each (at least one), starting with
        expression ``first`` (mod 6) so that a subject's sequences cover different expressions.

        Args:
            duration: sequence length, s.
            first: index of the first expression in :data:`ACTIVE_EXPRESSIONS`.
        """
        neutral = min(max(0.2 * duration, 0.5), 0.5 * duration)
        slots = max(1, min(len(ACTIVE_EXPRESSIONS), int((duration - neutral) / 2.0)))
        slot = (duration - neutral) / slots
        segments = []
        for k in range(slots):
            label = ACTIVE_EXPRESSIONS[(first + k) % len(ACTIVE_EXPRESSIONS)]
            start = neutral + k * slot + 0.1 * slot
            segments.append(
                ExpressionSegment(label, start, 0.2 * slot, 0.4 * slot, 0.2 * slot, 1.0)
            )
        return cls(tuple(segments))

    @classmethod
    def random(cls, duration: float, rng: np.random.Generator) -> ExpressionScript:
        """Test-sequence expressions: random labels, times, intensities and talking.

        Segments last 0.8 to 3.1 s (rise 0.2-0.5 s, hold 0.4-2 s, fall 0.2-0.6 s, peak 0.5-1)
        with 0.3 to 1.5 s of neutral between them; a jaw_open segment is talking (oscillating
        jaw) half the time.
        """
        segments = []
        time = rng.uniform(0.3, 1.0)
        while True:
            rise, hold, fall = rng.uniform(0.2, 0.5), rng.uniform(0.4, 2.0), rng.uniform(0.2, 0.6)
            if time + rise + hold + fall > duration:
                break
            label = ACTIVE_EXPRESSIONS[int(rng.integers(len(ACTIVE_EXPRESSIONS)))]
            talk = label == 'jaw_open' and bool(rng.integers(2))
            peak = float(rng.uniform(0.5, 1.0))
            segments.append(ExpressionSegment(label, time, rise, hold, fall, peak, talk))
            time = segments[-1].end + rng.uniform(0.3, 1.5)
        return cls(tuple(segments))
