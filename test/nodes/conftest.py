"""Each node test gets its own rclpy context on its own DDS domain, shut down afterwards."""
import itertools
import os
from typing import Iterator

import pytest
import rclpy

# A domain per test: nodes of an earlier test linger in DDS discovery for a while, and the
# lossless replay would wait for acknowledgements from them. The process id keeps parallel
# runs on one machine apart too.
_DOMAINS = itertools.count()


@pytest.fixture
def context() -> Iterator[rclpy.Context]:
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=1 + (os.getpid() * 7 + next(_DOMAINS)) % 100)
    try:
        yield ctx
    finally:
        rclpy.try_shutdown(context=ctx)
