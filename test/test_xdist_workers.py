"""Each pytest-xdist worker of `make test` runs its DDS nodes on a domain of its own."""

from __future__ import annotations

import pytest

from xdist_workers import worker_domain


@pytest.mark.parametrize(
    ('worker', 'domain', 'expected'),
    [('', '42', '42'), ('gw0', '42', '42'), ('gw1', '42', '43'), ('gw1', '232', '0')],
)
def test_a_worker_takes_the_domain_given_moved_by_its_index(monkeypatch, worker, domain, expected):
    if worker:
        monkeypatch.setenv('PYTEST_XDIST_WORKER', worker)
    else:
        monkeypatch.delenv('PYTEST_XDIST_WORKER', raising=False)
    assert worker_domain(domain) == expected
