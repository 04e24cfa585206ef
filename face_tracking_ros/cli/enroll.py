"""``face-tracking enroll BAG... --name NAME --gallery FILE``: enrol a person from a recording.

The offline counterpart of the identity_recognizer's ``enroll_identity`` service: the sigma
estimates of the TRACKING frames of tracker output bags (FaceState on ``face/state``) become the
person's entry in the gallery (created if missing, else extended; an existing entry of the same
name is replaced; estimates the gallery holds under another name are refused: the two entries
would tie).

A gallery holds one face model's sigma and records which model that is (its fingerprint); the
identity_recognizer refuses a gallery of another model. The model is ``--model``, else the one
the bags' metadata names (``track`` and ``replay`` record it), else the packaged default, as for
the identity_recognizer; a bag whose metadata names another model is refused.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import NamedTuple

import numpy as np

from face_tracking_ros.data import default_model_path
from face_tracking_ros.errors import BagError, ConfigError
from face_tracking_ros.io.atomic import check_output_path
from face_tracking_ros.io.bags import check_distinct_bags
from face_tracking_ros.io.provenance import tracked_with
from face_tracking_ros.io.series import load_states, require_parameters
from face_tracking_ros.model.model_file import load_model
from face_tracking_ros.recognition.identity import IdentityConfig, IdentityGallery
from face_tracking_ros.tracking.result import TrackStatus
from face_tracking_ros.wording import counted


def register(parser: argparse.ArgumentParser) -> None:
    """Register the ``enroll`` subcommand's options."""
    parser.description = __doc__.split('\n\n')[1].replace('``', '')
    parser.add_argument('bags', nargs='+', type=Path, metavar='BAG', help='tracker output bags')
    parser.add_argument('--name', required=True, help="the person's name")
    parser.add_argument('--gallery', required=True, type=Path, help='gallery file (.npz)')
    parser.add_argument(
        '--min-std',
        type=float,
        default=IdentityConfig().min_std,
        help="floor on the person's sigma standard deviation, m, kept in the gallery "
        '(identity_recognizer: identity.min_std; %(default)s)',
    )
    parser.add_argument(
        '--model',
        type=Path,
        help='face model the bags were tracked with (default: the one their metadata names, '
        'else the packaged default model)',
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    """Enrol and save the gallery.

    Raises:
        ConfigError: for an unusable ``--gallery`` path or ``--min-std``, bags tracked with
            different models or another than ``--model``, sigma of another p than the model's,
            or sigma the gallery holds under another name.
        BagError: if no frame of the bags was tracked with a sigma (:func:`tracked_sigmas`).
        ModelFileError: if the model or an existing gallery file is unusable or does not match.
    """
    check_distinct_bags(args.bags)
    check_output_path(args.gallery, '--gallery', parent_made=False)
    model_path = tracked_with(args.bags, args.model) or default_model_path()
    model = load_model(model_path)
    sigmas, not_finite = tracked_sigmas(args.bags)
    if sigmas.shape[1] != model.p:
        msg = f'the bags hold sigma of p={sigmas.shape[1]}, the model {model_path} has p={model.p}'
        raise ConfigError(msg)
    gallery = (
        IdentityGallery.load(args.gallery, model.p, model.fingerprint)
        if args.gallery.exists()
        else IdentityGallery.empty(model.p, model.fingerprint)
    )
    _check_not_enrolled_as_another(args, gallery, sigmas)
    replacing = f' (replacing the earlier {args.name!r})' if args.name in gallery.names else ''
    gallery = gallery.enroll(args.name, sigmas, IdentityConfig(min_std=args.min_std))
    gallery.save(args.gallery)
    print(
        f'enrolled {args.name!r}{replacing} from {len(sigmas)} shape estimates of the model '
        f'{model_path} (fingerprint {model.fingerprint}){_left_out(not_finite)}; '
        f'{args.gallery} holds {", ".join(gallery.names)}'
    )


def _left_out(not_finite: int) -> str:
    """What the enrolment says of the TRACKING frames it left out: none, or how many and why."""
    if not not_finite:
        return ''
    return f', leaving out {counted(not_finite, "TRACKING frame")} whose sigma has a NaN or inf'


def _check_not_enrolled_as_another(
    args: argparse.Namespace, gallery: IdentityGallery, sigmas: np.ndarray
) -> None:
    """Refuse sigma estimates the gallery holds under another name than ``args.name``.

    Raises:
        ConfigError: naming the entry (:meth:`IdentityGallery.enrolled_as`): under two names,
            the identity_recognizer could not tell them apart.
    """
    twin = gallery.enrolled_as(sigmas)
    if twin is not None and twin != args.name:
        msg = (
            f'{", ".join(map(str, args.bags))}: these {len(sigmas)} shape estimates are the '
            f'ones {args.gallery} holds as {twin!r} (the same mean sigma): enrolled as '
            f'{args.name!r} too, the identity_recognizer could not tell the two apart (they '
            f'tie); enrol them as {twin!r} to replace that entry, or enrol {args.name!r} from '
            'other recordings'
        )
        raise ConfigError(msg)


class TrackedSigmas(NamedTuple):
    """The sigma estimates enrolled from tracker output bags, and the TRACKING frames left out.

    Attributes:
        sigmas: (M, p) sigma of the TRACKING frames whose sigma is finite.
        not_finite: how many TRACKING frames were left out for a NaN or inf in their sigma.
    """

    sigmas: np.ndarray
    not_finite: int


def tracked_sigmas(bags: list[Path]) -> TrackedSigmas:
    """Sigma of the TRACKING frames of tracker output bags (those with a finite sigma).

    Raises:
        BagError: if no frame of the bags was tracked with a finite sigma, the states carry
            no sigma, or sigma of different p.
    """
    series = [load_states(bag) for bag in bags]
    for bag, states in zip(bags, series, strict=True):
        require_parameters(bag, {'sigma': states.sigma.shape[1]})
    widths = {bag: states.sigma.shape[1] for bag, states in zip(bags, series, strict=True)}
    if len(set(widths.values())) > 1:
        listed = ', '.join(f'{bag} p={p}' for bag, p in widths.items())
        msg = f'the bags hold sigma of different p ({listed}), tracked with different models'
        raise BagError(msg)
    tracking = np.concatenate([s.sigma[s.status == TrackStatus.TRACKING] for s in series])
    finite = np.all(np.isfinite(tracking), axis=1)
    not_finite = int(np.count_nonzero(~finite))
    if not finite.any():
        nan = counted(not_finite, 'has', 'have')
        frames = f'TRACKING frame whose sigma is finite ({nan} a NaN or inf)'
        msg = (
            f'no {frames if not_finite else "TRACKING frame"} in {", ".join(map(str, bags))}: '
            'nothing to enrol'
        )
        raise BagError(msg)
    return TrackedSigmas(tracking[finite], not_finite)
