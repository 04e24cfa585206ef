"""``face-tracking synth``: render synthetic face sequences with ground truth into MCAP bags.

Example::

    face-tracking synth --kind stereo --subjects 11 --sequences 2 --frames 120 --out data/train
    face-tracking synth --kind mono --frames 60 --motion free --out data/test
    face-tracking synth --contact-sheet docs/images/synthetic_contact_sheet.png

One bag per (subject, sequence) is written under ``--out`` (see
:mod:`face_tracking_ros.synthetic.recording` for the topics). The same arguments always write
byte-identical bags.
"""

from __future__ import annotations

import argparse
from pathlib import Path
import time

import cv2

from face_tracking_ros.errors import ConfigError
from face_tracking_ros.io.atomic import check_output_path
from face_tracking_ros.synthetic.contact_sheet import contact_sheet
from face_tracking_ros.synthetic.faces import PRESETS
from face_tracking_ros.synthetic.motion import Motion
from face_tracking_ros.synthetic.recording import RecordedBag, record
from face_tracking_ros.synthetic.scenes import (
    MAX_BASELINE,
    MAX_FOV_DEG,
    MAX_FPS,
    MAX_SIZE,
    MIN_BASELINE,
    MIN_FOV_DEG,
    MIN_SIZE,
    Kind,
    SceneConfig,
    focal_range,
)
from face_tracking_ros.synthetic.texture import ENCODINGS
from face_tracking_ros.wording import counted


def register(parser: argparse.ArgumentParser) -> None:
    """Register the ``synth`` subcommand's options."""
    low, high = focal_range(640)
    parser.description = (
        'Render synthetic subjects from a ground-truth face population into '
        'rosbag2 (MCAP) bags: images, camera infos and truth/face (pose, true alpha and sigma, '
        'nodes, expression label). One bag per subject and sequence.'
    )
    parser.add_argument(
        '--kind', choices=[k.value for k in Kind], default='stereo', help='default: %(default)s'
    )
    parser.add_argument(
        '--subjects', type=int, default=1, help='number of subjects, >= 1 (%(default)s)'
    )
    parser.add_argument(
        '--sequences', type=int, default=1, help='sequences per subject (%(default)s)'
    )
    parser.add_argument(
        '--frames', type=int, default=30, help='frames per sequence, >= 1 (%(default)s)'
    )
    parser.add_argument(
        '--fps',
        type=float,
        default=10.0,
        help=f'frame rate, Hz, in (0, {MAX_FPS:g}] (%(default)g)',
    )
    parser.add_argument(
        '--seed', type=int, default=0, help='seed of population and sequences (%(default)s)'
    )
    parser.add_argument(
        '--out', type=Path, help='directory receiving the bags (none: --contact-sheet alone)'
    )
    parser.add_argument(
        '--population', choices=PRESETS, default='default', help='default: %(default)s'
    )
    parser.add_argument(
        '--motion',
        choices=[m.value for m in Motion],
        default='still',
        help='still: training (head still, neutral start, expressions in turn); '
        'free: test (free head motion, random expressions); '
        'static: head, neutral face and light fixed, only sensor noise (jitter); '
        'default: %(default)s',
    )
    parser.add_argument(
        '--size',
        type=_size,
        default=(640, 480),
        help=f'WIDTHxHEIGHT, px, {MIN_SIZE} to {MAX_SIZE} a side (640x480)',
    )
    parser.add_argument(
        '--encoding', choices=ENCODINGS, default='mono8', help='default: %(default)s'
    )
    parser.add_argument(
        '--focal',
        type=float,
        default=600.0,
        help=f'focal length, px, for a horizontal field of view of {MAX_FOV_DEG:g} down to '
        f'{MIN_FOV_DEG:g} degrees ({low:.0f} to {high:.0f} px at 640 px wide; %(default)s)',
    )
    parser.add_argument(
        '--baseline',
        type=float,
        default=0.11,
        help=f'stereo baseline, m, {MIN_BASELINE} to {MAX_BASELINE} (%(default)s)',
    )
    parser.add_argument('--texture', type=Path, help='face photo used as every subject texture')
    parser.add_argument(
        '--texture-nodes', type=Path, help='JSON {node name: [x, y]} of the photo node pixels'
    )
    parser.add_argument(
        '--distortion',
        type=_coefficients,
        default=(),
        metavar='K1,K2,P1,P2,K3',
        help='plumb_bob coefficients of the cameras (raw images; default none); with a '
        'negative k1 write --distortion=-0.3,0.1,0,0,0 (argparse reads -0.3,... as an option)',
    )
    parser.add_argument(
        '--toe-in',
        type=float,
        default=0.0,
        metavar='DEG',
        help='cameras turned towards each other by DEG from their rectified frames (raw images, '
        'R in CameraInfo; default 0)',
    )
    parser.add_argument('--motion-blur', action='store_true', help='blur over the exposure')
    parser.add_argument('--occlusion', action='store_true', help='pass an occluder once')
    parser.add_argument(
        '--contact-sheet',
        type=Path,
        help='write a PNG contact sheet of this world here (with --out, besides the bags)',
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    """Render the bags (and the contact sheet) the arguments describe.

    Raises:
        ConfigError: for invalid arguments (counts < 1, missing texture files, ...).
    """
    if args.out is None and args.contact_sheet is None:
        raise ConfigError('give --out (bags) and/or --contact-sheet (PNG)')
    if args.out is not None:
        check_output_path(args.out, '--out', directory=True)
    if args.contact_sheet is not None:
        _check_contact_sheet(args.contact_sheet)
    width, height = args.size
    config = SceneConfig(
        kind=args.kind,
        subjects=args.subjects,
        sequences=args.sequences,
        frames=args.frames,
        fps=args.fps,
        seed=args.seed,
        population=args.population,
        motion=args.motion,
        width=width,
        height=height,
        encoding=args.encoding,
        focal=args.focal,
        baseline=args.baseline,
        texture=args.texture,
        texture_nodes=args.texture_nodes,
        motion_blur=args.motion_blur,
        occlusion=args.occlusion,
        distortion=args.distortion,
        toe_in_deg=args.toe_in,
    )
    if args.out is not None:
        started = time.perf_counter()
        bags = record(config, args.out, progress=_report)
        elapsed = time.perf_counter() - started
        frames = sum(bag.frames for bag in bags)
        images = frames * (2 if config.kind is Kind.STEREO else 1)
        megabytes = sum(bag.bytes for bag in bags) / 1e6
        print(
            f'{counted(len(bags), "bag")}, {counted(frames, "frame")} '
            f'({counted(images, "image")}) in {elapsed:.1f} s '
            f'({images / elapsed:.1f} images/s), {megabytes:.1f} MB'
        )
    if args.contact_sheet is not None:
        args.contact_sheet.parent.mkdir(parents=True, exist_ok=True)
        if not cv2.imwrite(str(args.contact_sheet), contact_sheet(config)):
            raise ConfigError(f'cannot write contact sheet {args.contact_sheet}')
        print(f'contact sheet: {args.contact_sheet}')


def _check_contact_sheet(path: Path) -> None:
    """Refuse a ``--contact-sheet`` that OpenCV cannot write, before any rendering.

    Raises:
        ConfigError: naming the option: a path OpenCV could not write into
            (:func:`~face_tracking_ros.io.atomic.check_output_path`), or a file name of an
            extension OpenCV writes no image format for.
    """
    check_output_path(path, '--contact-sheet')
    if not cv2.haveImageWriter(str(path)):
        msg = (
            f'--contact-sheet {path}: OpenCV writes no image format of its extension '
            f'({path.suffix or "none"}); give a .png (or .jpg, .tif...) file name'
        )
        raise ConfigError(msg)


def _report(bag: RecordedBag) -> None:
    """Print one written bag."""
    print(f'{bag.path}: {bag.subject_id} sequence {bag.sequence}, {counted(bag.frames, "frame")}, '
          f'{bag.bytes / 1e6:.1f} MB')  # fmt: skip


def _size(text: str) -> tuple[int, int]:
    """Parse WIDTHxHEIGHT."""
    try:
        width, height = (int(part) for part in text.lower().split('x'))
    except ValueError:
        raise argparse.ArgumentTypeError(f'size must be WIDTHxHEIGHT, got {text!r}') from None
    return width, height


def _coefficients(text: str) -> tuple[float, ...]:
    """Parse comma-separated numbers."""
    try:
        return tuple(float(part) for part in text.split(','))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f'expected numbers like -0.2,0.05,0,0,0: {text!r}'
        ) from None
