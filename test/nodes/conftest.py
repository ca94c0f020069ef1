"""Each node test gets its own rclpy context on its own DDS domain, shut down afterwards."""
from typing import Iterator

from absscale_ros.domains import DomainLease
import pytest
import rclpy

# A domain per test, leased machine-wide: nodes of an earlier test linger in DDS discovery
# for a while, and a graph of another run on the same domain would acknowledge our frames.


@pytest.fixture
def context() -> Iterator[rclpy.Context]:
    ctx = rclpy.Context()
    with DomainLease() as lease:
        rclpy.init(context=ctx, domain_id=lease.domain_id)
        try:
            yield ctx
        finally:
            rclpy.try_shutdown(context=ctx)
