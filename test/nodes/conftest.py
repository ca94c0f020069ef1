"""Each node test gets its own rclpy context on its own DDS domain, shut down afterwards."""
import os
from typing import Iterator

import pytest
import rclpy


@pytest.fixture
def context() -> Iterator[rclpy.Context]:
    ctx = rclpy.Context()
    # A domain of our own keeps parallel test runs on this machine from hearing each other.
    rclpy.init(context=ctx, domain_id=1 + os.getpid() % 100)
    try:
        yield ctx
    finally:
        rclpy.try_shutdown(context=ctx)
