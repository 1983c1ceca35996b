"""Every number in a drive-train or plant configuration is finite, typed and in its range.

Parametrised over every numeric field of every component of the FA320A preset: a value that
is infinite, NaN, absurdly large (1e30), a TOML boolean or a string is refused with a
ConfigError naming the component and field, never accepted or turned into a traceback.
"""

from __future__ import annotations

import copy
import math
import tomllib
from typing import Any

import pytest
from typer.testing import CliRunner

from drafttwin.cli import app
from drafttwin.errors import ConfigError
from drafttwin.mechanics.config import preset_path, spec_from_dict
from drafttwin.plant.config import PlantConfig

RAW = tomllib.loads(preset_path("fa320a").read_text(encoding="utf-8"))
BAD = {"inf": math.inf, "nan": math.nan, "1e30": 1e30, "true": True, "text": "50"}


def _numeric_fields() -> list[tuple[str, int | None, str]]:
    """(section, index in an array of tables or None, field) of every number in the preset."""
    out = []
    for section, body in RAW.items():
        items = list(enumerate(body)) if isinstance(body, list) else [(None, body)]
        for i, item in items:
            for field, value in item.items():
                if isinstance(value, int | float) and not isinstance(value, bool):
                    out.append((section, i, field))
    return out


FIELDS = _numeric_fields()


def _with(section: str, index: int | None, field: str, value: Any) -> dict[str, Any]:
    raw = copy.deepcopy(RAW)
    target = raw[section] if index is None else raw[section][index]
    target[field] = value
    return raw


def test_the_preset_has_many_numeric_fields() -> None:
    assert len(FIELDS) > 60  # the parametrisation below really walks the whole train


@pytest.mark.parametrize("bad", list(BAD), ids=list(BAD))
@pytest.mark.parametrize(("section", "index", "field"), FIELDS,
                         ids=[f"{s}[{i}].{f}" for s, i, f in FIELDS])  # fmt: skip
def test_a_bad_number_in_any_field_is_refused_by_name(
    section: str, index: int | None, field: str, bad: str
) -> None:
    with pytest.raises(ConfigError) as err:
        spec_from_dict(_with(section, index, field, BAD[bad]), source="bad.toml")
    assert field in err.value.message and "bad.toml" in err.value.message


def test_the_message_names_the_range() -> None:
    raw = _with("solver", None, "settle_s", 1e30)
    with pytest.raises(ConfigError, match="less than or equal to 3600"):
        spec_from_dict(raw, source="bad.toml")


def test_a_step_that_would_hang_the_integrator_is_refused() -> None:
    with pytest.raises(ConfigError, match="dt_s.*greater than or equal to"):
        spec_from_dict(_with("solver", None, "dt_s", 1e-12), source="bad.toml")


def test_the_cli_prints_one_error_and_exits_2(tmp_path) -> None:  # type: ignore[no-untyped-def]
    text = preset_path("fa320a").read_text(encoding="utf-8")
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace("settle_s = 1.0", "settle_s = inf"), encoding="utf-8")
    res = CliRunner().invoke(app, ["simulate", "--config", str(bad), "--duration", "0.1",
                                   "--out", str(tmp_path / "o.csv")])  # fmt: skip
    assert res.exit_code == 2
    assert "settle_s" in res.output and "finite" in res.output
    assert "Traceback" not in res.output and not (tmp_path / "o.csv").exists()


@pytest.mark.parametrize(
    ("section", "field", "value"),
    [("sensors", "missing_rate", True), ("sensors", "pulses_per_rev", 1e30),
     ("drafting_force", "cv", math.nan), ("thermal", "time_constant_s", math.inf),
     ("supply", "jitter_hz", "0.01"), ("drafting_force", "main_zone_mean_n", 1e30)],
)  # fmt: skip
def test_plant_settings_are_strict_and_finite(section: str, field: str, value: Any) -> None:
    with pytest.raises(ValueError, match=field):
        PlantConfig.model_validate({section: {field: value}})


def test_plant_settings_still_read_toml_arrays_as_pairs() -> None:
    cfg = PlantConfig.model_validate({"sensors": {"burst_length": [3, 9]}})
    assert cfg.sensors.burst_length == (3, 9)
