"""Domain leases keep concurrent graph runs and node tests on separate DDS domains."""
from pathlib import Path
import subprocess
import sys

from absscale_ros import domains
from absscale_ros.domains import DomainLease


def test_leases_are_exclusive_across_processes(tmp_path: Path) -> None:
    with DomainLease(tmp_path) as mine:
        # Another process must not get the domain this one holds.
        code = ('import sys; from pathlib import Path; from absscale_ros.domains import '
                f'DomainLease; print(DomainLease(Path({str(tmp_path)!r})).domain_id)')
        others = {int(subprocess.run([sys.executable, '-c', code], capture_output=True,
                                     text=True, check=True).stdout) for _ in range(3)}
        assert mine.domain_id not in others
        assert all(domains.FIRST <= d <= domains.LAST for d in others | {mine.domain_id})


def test_a_released_domain_rests_before_it_is_leased_again(tmp_path: Path) -> None:
    first = DomainLease(tmp_path)
    held = [DomainLease(tmp_path) for _ in range(domains.LAST - domains.FIRST - 1)]
    first.release()
    # One domain never used and the one just released are free: the fresh one wins.
    fresh = DomainLease(tmp_path)
    assert fresh.domain_id != first.domain_id
    again = DomainLease(tmp_path)  # only the resting one is left: taken rather than failing
    assert again.domain_id == first.domain_id
    for lease in (*held, fresh, again):
        lease.release()
