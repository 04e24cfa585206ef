"""``face-tracking overlay BAG OUT --video FILE``: the input frames with the tracked mesh drawn."""

from __future__ import annotations

import argparse
from pathlib import Path

from face_tracking_ros.errors import BagError, ConfigError
from face_tracking_ros.io.bags import bag_topics
from face_tracking_ros.io.conversions import STATE_TYPE
from face_tracking_ros.io.provenance import other_source
from face_tracking_ros.io.series import load_states
from face_tracking_ros.pipelines.bag_inputs import image_topics
from face_tracking_ros.visualization.video import write_overlay_video
from face_tracking_ros.wording import counted


def register(parser: argparse.ArgumentParser) -> None:
    """Register the ``overlay`` subcommand's options."""
    parser.description = (
        'Match the images of BAG with the FaceState outputs of OUT by stamp and '
        'write them, with the mesh drawn (green tracking, red lost), as an MP4 or a GIF.'
    )
    parser.add_argument('bag', type=Path, help='input bag (images)')
    parser.add_argument('out', type=Path, help='tracking output bag (face/state)')
    parser.add_argument('--video', type=Path, required=True, help='output .mp4 or .gif')
    parser.add_argument('--image-topic', help='image topic (default: the only one, or left)')
    parser.add_argument('--every', type=int, default=1, help='use every n-th frame (default 1)')
    parser.add_argument(
        '--no-rectify',
        dest='rectify',
        action='store_false',
        help='draw on the frames as recorded (images tracked with rectify:=false); by default '
        'they are rectified with their camera_info, as the trackers rectify them',
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    """Write the video, and say so when OUT records it was tracked from another bag than BAG.

    Raises:
        ConfigError: for ``--every`` < 1 or an unusable ``--video`` path.
        BagError: if OUT holds no face/state (saying so when the two bags came swapped), or
            BAG has no (or no such) image topic.
        InputError: for a frame that cannot be drawn.
    """
    if args.every < 1:
        msg = f'--every must be >= 1, got {args.every}'
        raise ConfigError(msg)
    try:
        states = load_states(args.out)
    except BagError as error:
        if _swapped(args.bag, args.out):
            msg = (
                f'{error}: the first argument is a tracking output and the second holds images: '
                'give the images bag first'
            )
            raise BagError(msg) from None
        raise
    count = write_overlay_video(
        args.bag, states, args.video, args.image_topic, args.every, rectify=args.rectify
    )
    print(f'wrote {counted(count, "frame")} to {args.video}')
    source = other_source(args.out, args.bag)
    if source is not None:  # a copy or another rendering of the bag may be meant: drawn
        print(
            f'note: {args.out} was tracked from {source}, not from {args.bag}: its meshes are '
            'drawn on the images of the same stamps'
        )


def _swapped(bag: Path, out: Path) -> bool:
    """Whether the bags came swapped: FaceState and no images in ``bag``, images in ``out``.

    Asked when ``out``'s states cannot be loaded (:func:`~face_tracking_ros.io.series.
    load_states`); False where either bag cannot be read, so that error stays the one raised.
    """
    try:
        first, second = bag_topics(bag), bag_topics(out)
    except BagError:
        return False
    tracked = STATE_TYPE in first.values() and not image_topics(first)[0]
    return tracked and bool(image_topics(second)[0])
