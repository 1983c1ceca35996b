"""Regenerate the embedded default data set: ``python -m drafttwin.datasets``."""

import time

from drafttwin.datasets import write_default

start = time.perf_counter()
path = write_default()
print(f"wrote {path} in {time.perf_counter() - start:.1f} s")
