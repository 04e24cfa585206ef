"""``face-tracking enroll BAG... --name NAME --gallery FILE``: enrol a person from a recording.

The offline counterpart of the identity_recognizer's ``enroll_identity`` service: the sigma
estimates of the TRACKING frames of tracker output bags (FaceState on ``face/state``) become the
person's entry in the gallery (created if missing, else extended; an existing entry of the same
name is replaced).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from face_tracking_ros.errors import BagError
from face_tracking_ros.io.series import load_states, require_parameters
from face_tracking_ros.recognition.identity import IdentityConfig, IdentityGallery
from face_tracking_ros.tracking.result import TrackStatus


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``enroll`` subcommand."""
    parser = subparsers.add_parser(
        'enroll',
        help='enrol a person in an identity gallery from tracked recordings',
        description=__doc__.split('\n\n')[1],
    )
    parser.add_argument('bags', nargs='+', type=Path, metavar='BAG', help='tracker output bags')
    parser.add_argument('--name', required=True, help="the person's name")
    parser.add_argument('--gallery', required=True, type=Path, help='gallery file (.npz)')
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    """Enrol and save the gallery."""
    sigmas = tracked_sigmas(args.bags)
    p = sigmas.shape[1]
    gallery = (
        IdentityGallery.load(args.gallery, p)
        if args.gallery.exists()
        else IdentityGallery.empty(p)
    )
    gallery = gallery.enroll(args.name, sigmas, IdentityConfig())
    gallery.save(args.gallery)
    print(
        f'enrolled {args.name!r} from {len(sigmas)} shape estimates; '
        f'{args.gallery} holds {", ".join(gallery.names)}'
    )


def tracked_sigmas(bags: list[Path]) -> np.ndarray:
    """(M, p) sigma of the TRACKING frames of tracker output bags (those with a sigma).

    Raises:
        BagError: if no frame of the bags was tracked, or the states carry no sigma.
    """
    series = [load_states(bag) for bag in bags]
    for bag, states in zip(bags, series, strict=True):
        require_parameters(bag, {'sigma': states.sigma.shape[1]})
    sigmas = [
        s.sigma[(s.status == TrackStatus.TRACKING) & np.all(np.isfinite(s.sigma), axis=1)]
        for s in series
    ]
    stacked = np.concatenate(sigmas) if sigmas else np.zeros((0, 0))
    if not len(stacked):
        msg = f'no TRACKING frame in {", ".join(map(str, bags))}: nothing to enrol'
        raise BagError(msg)
    return stacked
