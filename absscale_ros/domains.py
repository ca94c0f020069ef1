"""
DDS domain leases: every graph run and node test on this machine gets a domain of its own.

Two graphs on one domain hear each other: simulator bags share stamps, so one graph's
acknowledgements would complete the other's replay steps (seen as runs that skipped frames
while other tests ran). A lease is an exclusive ``flock`` on a file per domain, so it holds
across processes and dies with its holder. A released domain is left alone for ``QUIET_S``:
the departed participants linger in DDS discovery for a while.
"""
import fcntl
import os
from pathlib import Path
import tempfile
import time
from typing import IO

# ROS 2 on Linux: domains above 101 can collide with the kernel's ephemeral ports.
FIRST, LAST = 1, 101
QUIET_S = 20.0
RELEASED = 'released\n'


class DomainLease:
    """
    Hold a free domain id until ``release`` (or the process ends).

    :param lease_dir: where the lock files live (one per domain).
    """

    def __init__(self, lease_dir: Path | None = None) -> None:
        self._dir = lease_dir or Path(tempfile.gettempdir()) / 'absscale_domains'
        self._dir.mkdir(parents=True, exist_ok=True)
        self._file: IO[str] | None = None
        count = LAST - FIRST + 1
        start = os.getpid() * 7 + time.monotonic_ns() // 1000
        for quiet in (QUIET_S, 0.0):  # all recently used: take any unlocked one
            for i in range(count):
                domain = FIRST + (start + i) % count
                if self._try(domain, quiet):
                    self.domain_id = domain
                    return
        raise RuntimeError(f'all DDS domains {FIRST}-{LAST} are leased ({self._dir})')

    def _try(self, domain: int, quiet_s: float) -> bool:
        handle = open(self._dir / f'{domain}.lock', 'a+')
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            handle.close()
            return False
        handle.seek(0)
        released_s = time.time() - os.fstat(handle.fileno()).st_mtime
        if handle.read() == RELEASED and released_s < quiet_s:
            handle.close()  # closing drops the lock
            return False
        handle.seek(0)
        handle.truncate()
        self._file = handle
        return True

    def release(self) -> None:
        """Give the domain back, marked with the time of release."""
        if self._file is None:
            return
        self._file.write(RELEASED)
        self._file.flush()
        self._file.close()
        self._file = None

    def __enter__(self) -> 'DomainLease':
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()
