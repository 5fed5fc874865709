"""Domain picking (dds.domains.pick_domain_id): busy ports and leases, without ROS."""

from __future__ import annotations

import os
import time

import pytest
from apf_swarm_nodes.dds import domains


@pytest.fixture
def quiet(tmp_path, monkeypatch):
    """No bound port anywhere; lease files in a directory of this test."""
    monkeypatch.setenv('XDG_RUNTIME_DIR', str(tmp_path))
    monkeypatch.setattr(domains, '_bound_udp_ports', set)
    return tmp_path / 'apf_swarm-domains'


def test_picks_in_a_row_get_different_domains_until_the_range_is_leased(quiet) -> None:
    picked = {domains.pick_domain_id(lo=10, hi=13) for _ in range(4)}
    assert picked == {10, 11, 12, 13}
    # every domain leased: still an answer, from the range
    assert 10 <= domains.pick_domain_id(lo=10, hi=13) <= 13
    assert (quiet / '11').read_text().strip() == str(os.getpid())


def test_a_lease_expires_and_a_busy_port_excludes_a_domain(quiet, monkeypatch) -> None:
    assert domains.pick_domain_id(lo=5, hi=6, exclude=[6]) == 5
    old = time.time() - domains.DOMAIN_LEASE - 1
    os.utime(quiet / '5', (old, old))
    assert domains.pick_domain_id(lo=5, hi=6, exclude=[6]) == 5  # expired: free again
    # a port of domain 5's range is bound (7400 + 250 * 5): domain 6 is picked
    monkeypatch.setattr(domains, '_bound_udp_ports', lambda: {7400 + 250 * 5 + 10})
    assert domains.pick_domain_id(lo=5, hi=6) == 6
