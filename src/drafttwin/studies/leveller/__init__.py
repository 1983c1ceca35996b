"""``drafttwin benchmark leveller``: does the twin find the autoleveller's action point?

Seeded plant machines, each with a feed fault (long-wave count variation, a sliver running
out, piecings) and its leveller at a wrong action point (or with a sluggish drive, a drifting
infeed sensor): the record (at most 300 m of sliver) goes to
:func:`drafttwin.sliver.action_point.find_action_point`; the same machine's sliver is then
drafted again (the same fibres, every fibre) at other action points, and the simulated CV's
minimum over the action point is found by Brent's method. Scored: the recommendation against
that minimum (within 5 mm) and the CV the recommendation reaches against the minimum CV
(within 5 %). See docs/sliver.md.
"""

from drafttwin.studies.leveller.run import (
    CASE_KINDS,
    LevellerBenchConfig,
    plan,
    run_benchmark,
    run_case,
    summarise,
)

__all__ = ["CASE_KINDS", "LevellerBenchConfig", "plan", "run_benchmark", "run_case", "summarise"]
