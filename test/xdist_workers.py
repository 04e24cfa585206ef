"""A DDS domain of its own for each pytest-xdist worker (`make test` runs the suite on two).

Two workers' nodes on one domain would see each other's topics of the same names (every test's
nodes use the package's default topics), so worker ``gwK`` takes the domain ``ROS_DOMAIN_ID + K``;
without xdist (``pytest`` alone, ``-p no:xdist`` or ``-n 0``) the domain is the one given.
"""

from __future__ import annotations

import os

from face_tracking_ros.cli.bench import MAX_DOMAIN_ID


def worker_domain(domain: str) -> str:
    """The ROS domain of this test process: ``domain`` moved by the xdist worker's index.

    Args:
        domain: the environment's ROS_DOMAIN_ID (an integer's text).

    Returns:
        ``domain`` itself outside an xdist worker; else ``domain`` plus the worker's index,
        wrapped into [0, MAX_DOMAIN_ID].
    """
    worker = os.environ.get('PYTEST_XDIST_WORKER', '')
    if not worker.startswith('gw'):
        return domain
    return str((int(domain) + int(worker[2:])) % (MAX_DOMAIN_ID + 1))
