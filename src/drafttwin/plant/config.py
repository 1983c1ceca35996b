"""Plant emulator settings: every magnitude with its source or marked as an assumption.

Sources are the numbered references of ``docs/sources.md`` (written [dN] here);
``docs/plant.md`` carries the same table for users. None of these values was chosen by looking
at how any model performs on the resulting data.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field

Frac = Annotated[float, Field(ge=0, le=1)]
NonNeg = Annotated[float, Field(ge=0, le=1e9)]
Pos = Annotated[float, Field(gt=0, le=1e9)]
GearRunoutLaw = Literal["rayleigh", "allowable"]
PlantStart = Literal["run-up", "operating-point"]


class _Cfg(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, strict=True, allow_inf_nan=False)


class Mismatch(_Cfg):
    """True parameters differ from the nominal preset by a seeded draw within these ranges.

    Each value is a relative half-range: the true value is nominal * (1 + u), u ~ U(-r, r).
    """

    friction_coefficient: Frac = 0.15  # assumption: mu 0.1 is the paper's round number
    belt_axial_rigidity: Frac = 0.30  # assumption: creep 0.5-1 % spans a factor 2 [d19]
    mesh_stiffness: Frac = 0.15  # ISO 6336-1: light load lowers c' by up to 30 % [d2.4]
    roller_torsion: Frac = 0.10  # assumption: G and roller length tolerances
    chain_span_stiffness: Frac = 0.20  # assumption
    breakdown_torque_ratio: Frac = 0.07  # assumption: lambda 2.5-3 around 2.8 [d2.1]
    bearing_friction: Frac = 0.30  # assumption: mu_b 0.0010-0.0015 [d18]


class DraftingForce(_Cfg):
    """Drafting force of the sliver: a colored random process, acting between roller pairs.

    The force in a zone pulls back the faster (delivering) roller and forward the slower one.
    Its fluctuation follows the sliver mass variation (force CV correlates with short-term
    irregularity [d7]); modelled as the sum of two Ornstein-Uhlenbeck processes (short
    correlation time of sliver irregularity at the feed, and slow drift).
    """

    main_zone_mean_n: NonNeg = 15.0  # 5-30 N for the whole strand (assumption [d2][d7][d8])
    break_zone_mean_n: NonNeg = 8.0  # smaller in the break zone (assumption)
    cv: Frac = 0.10  # 5-15 % (assumption, trends [d7])
    fast_correlation_s: Pos = 0.2  # assumption: ~0.9 m of sliver at the 4.3 m/s delivery
    slow_correlation_s: Pos = 20.0  # assumption: can changes, batch variation
    slow_share: Frac = 0.4  # share of the variance in the slow component (assumption)


class Eccentricity(_Cfg):
    """Once-per-revolution effects of run-out."""

    gear_runout_um: NonNeg = 35.0  # F_r 25-45 um, ISO 1328 grade 7-8, d 50-125 mm [d3]
    # ISO 1328's F_r is the ALLOWABLE run-out: an accepted gear's own lies below it. "rayleigh":
    # each gear's eccentricity vector is 2-D normal (the law of eccentricity [d23]), its length
    # Rayleigh with 99.73 % of gears within F_r / 2 (a process that just holds the tolerance,
    # C_p = 1 [d24]); its angle is the gear's random phase. "allowable": every gear exactly at
    # F_r / 2, the worst accepted gear everywhere (half of all machines then show a 14.14-cm
    # chimney, docs/sliver.md; the default until 2026-11-29, still the embedded data set's).
    # Why each gear's own is the default: docs/sliver.md, "Each gear's own run-out, the default"
    gear_runout_law: GearRunoutLaw = "rayleigh"
    roller_load_modulation: Frac = 0.05  # assumption: TIR 10-30 um on the cot's compliance
    # radius eccentricity of every bottom roller, the same run-out as roller_load_modulation
    # (long radius where the load is highest): it moves the surface speed once per revolution
    roller_eccentricity_um: NonNeg = 10.0  # assumption: half of a TIR of 10-30 um


class ThermalDrift(_Cfg):
    """Rotor warming raises the rotor resistance, hence the slip at a given torque."""

    warmup_kelvin: NonNeg = 40.0  # +40 K warm-up [d3 table, physics]
    time_constant_s: Pos = 1800.0  # assumption: 30 min thermal time constant of a 5.5 kW motor
    resistance_per_kelvin: NonNeg = 0.004  # copper/aluminium +0.4 %/K [d3 table]
    elapsed_at_start_s: NonNeg = 600.0  # assumption: recording starts 10 min after start-up


class Supply(_Cfg):
    """Frequency fluctuation of the VFD output (drives the synchronous speed)."""

    jitter_hz: NonNeg = 0.005  # assumption: VFD resolution 0.01 Hz [d3 table]
    correlation_s: Pos = 5.0  # assumption


class Sensors(_Cfg):
    """Encoders counting pulses over each sample window, plus the data path's defects."""

    pulses_per_rev: Annotated[int, Field(ge=1, le=1_000_000)] = (
        2500  # 500-2500 ppr [d21], assumption
    )
    quadrature: Annotated[int, Field(ge=1, le=4)] = 4  # x4 decoding [d21]
    clock_jitter_s: NonNeg = 2e-6  # assumption: sample-window length jitter
    missing_rate: Frac = 0.002  # assumption: single dropped samples (network, [paper 3.2])
    burst_rate_per_min: NonNeg = 1.0  # assumption: bursts of dropped samples per minute
    burst_length: Annotated[tuple[int, int], Field(strict=False)] = (
        5,
        50,
    )  # assumption: samples per burst (min, max)
    outlier_rate: Frac = 0.0005  # assumption: spikes (bit errors), per sample and roller
    outlier_size: Annotated[tuple[float, float], Field(strict=False)] = (
        0.15,
        0.40,
    )  # assumption: relative size, > 10 %


class PlantConfig(_Cfg):
    """All plant settings; the defaults are the documented FA320A plant."""

    mismatch: Mismatch = Mismatch()
    backlash_module_fraction: NonNeg = 0.04  # 2b = 0.04 m [d14]
    drafting_force: DraftingForce = DraftingForce()
    eccentricity: Eccentricity = Eccentricity()
    thermal: ThermalDrift = ThermalDrift()
    supply: Supply = Supply()
    sensors: Sensors = Sensors()
    start: PlantStart = "run-up"
    # How a record's machine reached its set-point. "run-up": from rest along a ramp
    # (scenarios.RUN_UP_S), then SETTLE_S at the set-point, as every real machine does.
    # "operating-point": placed at full speed with the static deflections and every excitation
    # switched on at once (the plant until 2026-12-01, still the embedded data set's); a
    # lightly loaded backlash mesh can then land in a rattle state (period doubling) that no
    # run-up reaches: 3 of 39 healthy machines rattled so, 0 after a run-up (docs/plant.md)
