"""Physics sources: the mechanistic prediction as a model input (:class:`MechanisticModel`:
a drive train, simulator output files, a table, a callable or an array), the simulator files
it reads (:mod:`.simfiles`) and the one parser of a source as a command names it
(:mod:`.source`); what a source gives, checked (:mod:`.values`)."""

from drafttwin.models.mechanistic.model import (
    MechanisticModel,
    as_mechanistic,
    describe_spec,
    spec_cutoff_hz,
)
from drafttwin.models.mechanistic.simfiles import record_names
from drafttwin.models.mechanistic.values import RecordFunction

__all__ = [
    "MechanisticModel",
    "RecordFunction",
    "as_mechanistic",
    "describe_spec",
    "record_names",
    "spec_cutoff_hz",
]
