"""The physics a fit, a prediction or an evaluation uses: the one place that resolves it.

A source given (a :class:`~drafttwin.models.MechanisticModel`, anything it accepts, or its
command-line text ``preset[:NAME]`` / ``config:FILE.toml`` / simulator files) is used; a
fitted model without one uses the source its file holds; a new hybrid on the FA320A's roller
channels uses the FA320A preset. A new model's drive train is reduced (couplings above
:data:`~drafttwin.mechanics.DEFAULT_CUTOFF_HZ` rigid) unless ``full_model``; a fitted model's
is simulated as it was fitted."""

from __future__ import annotations

from collections.abc import Sequence

from drafttwin._constants import ROLLERS
from drafttwin.errors import ConfigError
from drafttwin.mechanics import DEFAULT_CUTOFF_HZ, DriveTrain
from drafttwin.models import BaseModel, MechanisticModel
from drafttwin.models.mechanistic import describe_spec, spec_cutoff_hz

DEFAULT_PRESET = "fa320a"
"""The physics of a new hybrid on the roller channels when none is given."""


def resolve_physics(
    source: object | None,
    model: BaseModel,
    channels: Sequence[str] | None,
    *,
    full_model: bool = False,
    time_column: str | None = None,
) -> MechanisticModel | None:
    """The physics ``model`` uses on data with output ``channels`` (``None``: the model needs
    none; refused: one given to a model that uses none, none for a new hybrid on channels that
    are not the FA320A rollers, a fitted model whose file does not hold its source).
    ``time_column``: the records' time column's name, accepted in simulator files too."""
    if not model.needs_mechanistic:
        if source is not None:
            raise ConfigError(f"the {model.name} model uses no mechanistic source",
                              param="mechanistic", terms={"mechanistic": None},
                              fix="leave {mechanistic:name} out")  # fmt: skip
        return None
    fitted = getattr(model, "mechanistic_spec_", None)
    is_fitted = hasattr(model, "channels_")
    cutoff_hz = spec_cutoff_hz(fitted) if is_fitted else (None if full_model else DEFAULT_CUTOFF_HZ)
    if isinstance(source, str):
        return MechanisticModel.from_option(source, cutoff_hz=cutoff_hz, time_column=time_column)
    if isinstance(source, DriveTrain):
        from drafttwin.mechanics import reduce

        train = source if cutoff_hz is None or source.reduction else reduce(source, cutoff_hz)
        return MechanisticModel.from_train(train)
    if source is not None:
        return source if isinstance(source, MechanisticModel) else MechanisticModel(source)
    if is_fitted:
        restored = MechanisticModel.from_spec(fitted)
        if restored is None:
            raise ConfigError(
                f"the model was fitted with {describe_spec(fitted)}, which the model file does "
                "not hold",
                param="mechanistic", terms={"mechanistic": None},
                fix="pass the mechanistic source again with {mechanistic:name}",
            )  # fmt: skip
        return restored
    if channels is not None and tuple(channels) != ROLLERS:
        raise ConfigError(
            f"the {model.name} model needs the physics of the channels {', '.join(channels)}",
            param="mechanistic", terms={"mechanistic": None},
            fix="give {mechanistic:name}: config:YOUR_TRAIN.toml, a drive train or a simulator "
            "output file (time + those columns)",
        )  # fmt: skip
    return MechanisticModel.from_preset(DEFAULT_PRESET, cutoff_hz=cutoff_hz)
