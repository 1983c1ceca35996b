"""Physics sources: the mechanistic prediction as a model input (:class:`MechanisticModel`:
a drive train, simulator output files, a table, a callable or an array), the simulator files
it reads (:mod:`.simfiles`) and the one parser of a source as a command names it
(:mod:`.source`)."""

from drafttwin.models.mechanistic.model import (
    MechanisticModel,
    RecordFunction,
    as_mechanistic,
    describe_spec,
    record_names,
    spec_cutoff_hz,
)

__all__ = [
    "MechanisticModel",
    "RecordFunction",
    "as_mechanistic",
    "describe_spec",
    "record_names",
    "spec_cutoff_hz",
]
