import subprocess
import sys

import pytest

from reglib._alloc import retain_freed_memory

# In a fresh interpreter: RSS before and after freeing a 12 MiB array (MiB), optionally after
# retain_freed_memory(). Run apart so this test process keeps its own allocator settings.
_PROBE = """
import os, sys
import numpy as np
from reglib._alloc import retain_freed_memory
took = retain_freed_memory() if sys.argv[1] == "retain" else None
page = os.sysconf("SC_PAGE_SIZE") / 2**20
rss = lambda: int(open("/proc/self/statm").read().split()[1]) * page
a = np.ones(12 * 2**20 // 8)
held = rss()
del a
print(took, held - rss())
"""


def _freed_mib(mode: str) -> tuple[str, float]:
    out = subprocess.run([sys.executable, "-c", _PROBE, mode], capture_output=True, text=True, check=True).stdout
    took, freed = out.split()
    return took, float(freed)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt and /proc are Linux's")
def test_freed_memory_is_kept_for_reuse_only_when_asked():
    _, given_back = _freed_mib("default")
    took, kept_back = _freed_mib("retain")
    assert given_back > 10.0  # by default the 12 MiB go straight back to the system
    assert took == "True" and kept_back < 1.0  # retained: freeing it returns nothing


def test_elsewhere_it_says_it_did_nothing(monkeypatch):
    monkeypatch.setattr(sys, "platform", "darwin")
    assert retain_freed_memory() is False
