"""``drafttwin benchmark faults``: seeded faulty and healthy plant records, the twin's
diagnosis and baselines scored as fault-diagnosis benchmarks do (docs/faults.md)."""

from drafttwin.benchmarks.faults.run import run_benchmark

__all__ = ["run_benchmark"]
