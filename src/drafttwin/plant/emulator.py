"""The plant emulator: the machine that produces "measured" roller speeds.

The plant is the drive-train model with true parameters plus the effects the nominal
mechanistic model leaves out (:mod:`drafttwin.plant.effects`), measured by encoders through
a data path with defects (:mod:`drafttwin.plant.sensors`). The true speeds are kept beside
the measured ones, so the sensor's error and the floor of any prediction are known
(:mod:`drafttwin.evaluation.limits`).
"""

from __future__ import annotations

import contextlib
import copy
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from drafttwin._constants import ROLLERS, __version__
from drafttwin._io import atomic_path
from drafttwin._json import dumps_strict
from drafttwin.data.io import attach_truth as attach_truth  # re-exported (moved to data)
from drafttwin.data.series import MeasurementSeries
from drafttwin.errors import ConfigError, DataError
from drafttwin.mechanics import DriveTrain, Signal, reduce, simulate
from drafttwin.mechanics.reduced import describe as describe_reduction
from drafttwin.plant.config import PlantConfig
from drafttwin.plant.effects import FORCE_GRID_S, Disturbances, disturbances
from drafttwin.plant.faults import (
    FaultSchedule,
    FaultSpec,
    apply_sensor_faults,
    block_seconds,
    check_faults,
    eccentricity_torques,
    rotor_resistance_signal,
)
from drafttwin.plant.machine import Machine
from drafttwin.plant.scenarios import RUN_UP_S, get_scenario
from drafttwin.plant.sensors import encoder_rpm, inject_defects, quantisation_step_rpm
from drafttwin.plant.sliver_channel import (
    SURFACE_RATE_HZ,
    SliverChannel,
    SliverSettings,
    make_sliver,
    sliver_paths,
)
from drafttwin.plant.surface import (
    RollerSurface,
    roller_surface,
    run_outs,
    simulate_surface,
    surface_factor,
    surface_info,
)

STREAMS = (
    "mismatch", "supply", "drafting", "runout", "encoder", "missing", "outlier", "motor_encoder",
    "fault", "sliver",
)  # fmt: skip
"""One random stream per effect, spawned from the seed in this order: a stream added at the
end leaves the earlier ones (and so the files older versions wrote) unchanged."""
SETTLE_S = 1.0
RUN_UP_RATE_HZ = 100.0
"""Output rate of the run-up simulated alone for the rollers' angles (Plant._angles_after_run_up)."""


@dataclass(frozen=True)
class PlantRecording:
    """One run of the plant: measured series, true speeds and the record of injected defects.

    Attributes:
        series: measured roller speeds (rpm, NaN where dropped) with the VFD set-point
            (``setpoints["supply_hz"]``) and provenance in ``metadata``.
        true_rpm: true interval-mean roller speeds (rpm), shape ``(n, 4)``.
        true_motor_rpm: true interval-mean motor speed (rpm).
        missing, outlier: where the data path dropped samples / put spikes, bool ``(n, 4)``.
        info: seed, scenario, configuration, true parameters (JSON-able).
        surface: the bottom rollers' true surface lengths at a fine rate (with their radius
            run-out), only where the run asked for them (``surface_rate_hz``); not written
            to files (``info["surface"]`` records how they were made).
        true_motor_torque_nm: the motor's true interval-mean air-gap torque (N m: its work
            over the interval over the angle turned), what a drive's torque or current
            estimate would follow; not written to files (a study of what such a channel
            would add: ``drafttwin.studies.faults.torque_channel``).
    """

    series: MeasurementSeries
    true_rpm: np.ndarray
    true_motor_rpm: np.ndarray
    missing: np.ndarray
    outlier: np.ndarray
    info: dict[str, Any] = field(default_factory=dict)
    surface: RollerSurface | None = None
    sliver: SliverChannel | None = None
    true_motor_torque_nm: np.ndarray | None = None

    def truth_frame(self) -> pd.DataFrame:
        cols: dict[str, np.ndarray] = {"time": self.series.time_s}
        for j, r in enumerate(ROLLERS):
            cols[f"true_{r}"] = self.true_rpm[:, j]
        cols["true_motor"] = self.true_motor_rpm
        for j, r in enumerate(ROLLERS):
            cols[f"missing_{r}"] = self.missing[:, j]
        for j, r in enumerate(ROLLERS):
            cols[f"outlier_{r}"] = self.outlier[:, j]
        return pd.DataFrame(cols)

    def write(self, path: str | Path) -> list[Path]:
        """Write the measured file, ``<stem>.truth<suffix>`` and the ``<stem>.json`` sidecar.

        All three are written to temporary files first and renamed together at the end.
        """
        from drafttwin.data.io import write_measurements

        path = Path(path)
        suffix = path.suffix.lower()
        if suffix not in (".csv", ".parquet"):
            raise DataError(
                f"cannot write '{path.suffix or '(no suffix)'}' files",
                source=path,
                where="--out",
                fix="name the output *.csv or *.parquet",
            )
        truth = path.with_name(f"{path.stem}.truth{path.suffix}")
        sidecar = path.with_suffix(".json")
        files = {"measured": path.name, "truth": truth.name}
        written = [path, truth, sidecar]
        sliver_files = sliver_paths(path)
        if self.sliver is not None:
            files |= {"sliver": sliver_files[0].name, "sliver_truth": sliver_files[1].name}
            written += list(sliver_files)
        info = {**self.info, "files": files}
        with contextlib.ExitStack() as stack:
            if self.sliver is not None:
                self.sliver.write(*sliver_files, stack)
            tmp_sidecar = stack.enter_context(atomic_path(sidecar))
            tmp_truth = stack.enter_context(atomic_path(truth))
            measured = replace(self.series, metadata={"sidecar": sidecar.name})
            write_measurements(measured, stack.enter_context(atomic_path(path)))
            frame = self.truth_frame()
            if suffix == ".parquet":
                frame.to_parquet(tmp_truth, index=False)
            else:
                frame.to_csv(tmp_truth, index=False, float_format="%.17g")
            tmp_sidecar.write_text(dumps_strict(info, sort_keys=True) + "\n", encoding="utf-8")
        return written


class Plant:
    """The FA320A plant (or any drive train's), seeded and reproducible.

    Args:
        train: the nominal drive train (default: the ``fa320a`` preset); the plant draws its
            true parameters around it.
        config: effect magnitudes and sensor settings (:class:`PlantConfig`).
        reduced_hz: None (the default): the plant integrates the machine's full drive train.
            A cut-off in Hz: it integrates the machine's train reduced at that cut-off
            (:func:`~drafttwin.mechanics.reduce`: couplings above it rigid, belts compliant;
            at 200 Hz about 80 times cheaper). It loses what the rigid couplings do (mesh and
            chain vibration, backlash, gear transmission error): the rollers' and motor's
            1-s levels match the full plant's, their parity, the angle lags and the encoders'
            runs of repeated counts do not, so it is no stand-in for the full plant's healthy
            running in the fault detector (:mod:`drafttwin.studies.faults.generator`,
            docs/faults.md). Machine faults (time-varying parameters) and roller surfaces
            need the full train and are refused. The sidecar records it (``info["reduced"]``).
    """

    def __init__(self, train: DriveTrain | None = None, config: PlantConfig | None = None,
                 reduced_hz: float | None = None) -> None:  # fmt: skip
        self.train = train if train is not None else DriveTrain.preset("fa320a")
        self.config = config if config is not None else PlantConfig()
        if reduced_hz is not None:
            reduce(self.train, reduced_hz)  # refuses a cut-off that is not a frequency
        self.reduced_hz = reduced_hz
        declared = {r.name for r in self.train.spec.roller}
        if not set(ROLLERS) <= declared:
            raise ConfigError(
                "the plant emulator plays a drawing frame's drafting section (sliver drafted "
                "between roller pairs, roller encoders); this train declares "
                + (f"the rollers {', '.join(sorted(declared))}" if declared else "no rollers")
                + f", not {', '.join(ROLLERS)}",
                source=self.train.source,
                where="[[roller]]",
                fix="generate with --preset fa320a or a drafting train with these four rollers; "
                "for another machine record its data, or simulate it (drafttwin simulate)",
            )

    def run(
        self,
        duration_s: float,
        rate_hz: float = 100.0,
        seed: int = 0,
        scenario: str = "steady",
        progress: Callable[[float], None] | None = None,
        machine: Machine | None = None,
        faults: Sequence[FaultSpec] = (),
        surface_rate_hz: float | None = None,
        sliver: SliverSettings | None = None,
    ) -> PlantRecording:
        """Run the plant for ``duration_s`` seconds, sampled at ``rate_hz``.

        ``seed`` draws the recording (noise, drafting force, supply jitter, data-path
        defects, thermal state is the config's); ``machine`` is the machine recorded (its
        true parameters; default: the one :meth:`machine` draws from ``seed``), so two
        recordings of one machine share ``machine`` and differ in ``seed``. ``faults`` are
        injected machine and sensor faults (:mod:`drafttwin.plant.faults`), labelled in
        ``info["faults"]``; none leaves the run exactly as it was. ``surface_rate_hz`` (a
        whole multiple of ``rate_hz``) adds the rollers' true surface lengths at that rate
        (``surface``, :mod:`drafttwin.plant.surface`); every other output stays bit for bit
        what it is without it. ``sliver`` makes sliver (:mod:`drafttwin.plant.sliver_channel`):
        the true rollers' surfaces at 2 kHz (unless ``surface_rate_hz`` says otherwise)
        draft the fed slivers, the delivery and infeed sensors read them (``sliver``).
        """
        if sliver is not None and surface_rate_hz is None:
            surface_rate_hz = SURFACE_RATE_HZ
        if surface_rate_hz is not None:
            surface_factor(surface_rate_hz, rate_hz)
        scen = get_scenario(scenario)
        streams = _streams(seed)
        if machine is None:
            machine = Machine.draw(self.train, self.config, seed)
        plant_train, draws = machine.train, machine.draws
        motor = self.train.spec.motor
        if motor is None:
            raise ConfigError(
                "the plant runs its scenarios through the motor's supply, but the train has no "
                "motor",
                source=self.train.source,
                where="[motor]",
                fix="add a [motor] to the train",
            )
        nominal_hz = motor.supply_hz
        setpoint = scen.setpoint(duration_s, nominal_hz)
        settle = 0.0 if scen.from_rest else SETTLE_S
        # a machine recorded running got there by running up from rest (PlantConfig.start)
        run_up = RUN_UP_S if self.config.start == "run-up" and not scen.from_rest else 0.0
        faults = check_faults(faults, plant_train)
        if self.reduced_hz is not None:
            _check_reducible(faults, surface_rate_hz)
        angles_at = None
        if run_up > 0:
            angles_at = self._angles_after_run_up(plant_train, setpoint, settle, streams, run_up)
        dist = disturbances(plant_train, self.config, setpoint, -settle, duration_s, streams,
                            run_up_s=run_up, roller_angle_rad=angles_at)  # fmt: skip
        driven, schedule, ecc_phase = _driven_train(plant_train, dist, faults, setpoint, -settle,
                                                    duration_s, streams["fault"], angles_at)  # fmt: skip
        if self.reduced_hz is not None:
            driven = reduce(driven, self.reduced_hz)
        surface, surface_record = None, None
        settle_s, from_rest = settle + run_up, scen.from_rest or run_up > 0
        if surface_rate_hz is None:
            res = simulate(driven, duration_s, output_rate_hz=rate_hz, settle_s=settle_s,
                           from_rest=from_rest, progress=progress, tables_at=schedule)  # fmt: skip
        else:
            res, angles = simulate_surface(driven, duration_s, rate_hz=rate_hz,
                                           surface_rate_hz=surface_rate_hz, settle_s=settle_s,
                                           from_rest=from_rest, progress=progress,
                                           tables_at=schedule)  # fmt: skip
            surface, surface_record = _surface(plant_train, self.config, dist, faults, ecc_phase,
                                               angles, surface_rate_hz)  # fmt: skip
        true_rpm = res.roller_rpm()
        sensors = self.config.sensors
        counted = encoder_rpm(true_rpm, 1.0 / rate_hz, sensors, streams["encoder"])
        measured = inject_defects(counted, rate_hz, sensors, streams["missing"], streams["outlier"])
        # the motor's own encoder (or the VFD's speed feedback), on the same logger rows
        motor_counted = encoder_rpm(res.motor_rpm[:, None], 1.0 / rate_hz, sensors,
                                    streams["motor_encoder"])[:, 0]  # fmt: skip
        motor_measured = np.where(measured.missing[:, 0], np.nan, motor_counted)
        if any(f.is_sensor for f in faults):
            rpm, motor_measured, lost = apply_sensor_faults(
                measured.rpm, motor_measured, res.time_s, faults, streams["fault"])  # fmt: skip
            measured = replace(measured, rpm=rpm, missing=measured.missing | lost)
        info = {
            "generator": f"drafttwin {__version__} plant emulator",
            "seed": seed,
            "scenario": scenario,
            "scenario_description": scen.description,
            "duration_s": duration_s,
            "rate_hz": rate_hz,
            "plant_config": _config_record(self.config, surface=surface is not None),
            "true_train": plant_train.to_dict(),
            "mismatch_draws": draws,
            "machine": machine.describe(),
            "quantisation_step_rpm": quantisation_step_rpm(sensors, rate_hz),
            "faults": [f.label(block_seconds(rate_hz)) for f in faults],
            "injected": {
                "missing_rows": int(measured.missing[:, 0].sum()),
                "outliers": {r: int(measured.outlier[:, j].sum()) for j, r in enumerate(ROLLERS)},
            },
        }
        if surface_record is not None:
            info["surface"] = surface_record
        if self.reduced_hz is not None:
            info["reduced"] = describe_reduction(driven)
        channel = None
        if sliver is not None and surface is not None:
            channel = make_sliver(surface.time_s, surface.length_m, sliver, streams["sliver"],
                                  seed)  # fmt: skip
            info["sliver"] = channel.summary
        series = MeasurementSeries(
            time_s=res.time_s,
            values=measured.rpm,
            inputs={"supply_hz": setpoint.at(res.time_s)},
            truth=true_rpm,
            motor_rpm=motor_measured,
            metadata={"source": "drafttwin plant", "seed": seed, "scenario": scenario},
        )
        return PlantRecording(
            series,
            true_rpm,
            res.motor_rpm,
            measured.missing,
            measured.outlier,
            info,
            surface,
            channel,
            _motor_torque_nm(res.energy_j[:, 0], res.motor_rpm, rate_hz),
        )

    def _angles_after_run_up(self, train: DriveTrain, setpoint: Signal, settle_s: float,
                             streams: dict[str, np.random.Generator],
                             run_up_s: float) -> dict[str, float]:  # fmt: skip
        """Each roller's angle (rad, by roller name) where its run-up ends and the record's
        settling run starts: the run-up alone, with the record's inputs (its draws copied, so
        the record's are left as they are), on the train reduced below 200 Hz (0.02 s instead
        of 1 s; within 3.2 mrad of the full train's angles on machines 7, 4711 and 5), at
        one output rate whatever the record's (the reduced step depends on it, and a record
        with its surfaces must keep the numbers of one without). A run-out load starts there
        in phase with its roller's radius (the load is open loop, and the rollers lag the
        set-point's integral while they accelerate)."""
        # only the run-up's inputs are needed, and they take the first values of the draws:
        # a run of the disturbances to the run-up's end is a prefix of the record's
        probe = disturbances(train, self.config, setpoint, -settle_s, -settle_s,
                             copy.deepcopy(streams), run_up_s=run_up_s)  # fmt: skip
        driven, _, _ = _driven_train(train, probe, (), setpoint, -settle_s, -settle_s,
                                     streams["fault"])  # fmt: skip
        res = simulate(reduce(driven), run_up_s, output_rate_hz=RUN_UP_RATE_HZ, settle_s=0.0,
                       t_start_s=-(settle_s + run_up_s), from_rest=True, angles=True)  # fmt: skip
        assert res.angle_rad is not None
        return {str(r.name): float(res.angle_rad[-1, train.node_index(r.node)])
                for r in train.spec.roller}  # fmt: skip


def _motor_torque_nm(work_j: np.ndarray, motor_rpm: np.ndarray, rate_hz: float) -> np.ndarray:
    """Interval-mean motor torque from its work accumulator (J at each interval end, counted
    from the record's start) and its interval-mean speed (rpm)."""
    power_w = np.diff(np.concatenate([[0.0], work_j])) * rate_hz
    with np.errstate(divide="ignore", invalid="ignore"):
        torque: np.ndarray = np.where(motor_rpm > 0, power_w / (motor_rpm * np.pi / 30.0), np.nan)
    return torque


def _check_reducible(faults: Sequence[FaultSpec], surface_rate_hz: float | None) -> None:
    """A reduced plant records healthy running (sensor faults allowed), nothing else."""
    machine = sorted({f.kind for f in faults if not f.is_sensor})
    if machine or surface_rate_hz is not None:
        raise ConfigError(
            "a reduced plant (reduced_hz) integrates the machine with its stiff couplings "
            "rigid, so it cannot play "
            + (f"the machine faults {', '.join(machine)}" if machine else "roller surfaces"),
            where="reduced_hz",
            fix="record faults and surfaces with the full plant (reduced_hz=None)",
        )


def _surface(train: DriveTrain, cfg: PlantConfig, dist: Disturbances, faults: Sequence[FaultSpec],
             ecc_phase: dict[str, float], angles: np.ndarray,
             rate_hz: float) -> tuple[RollerSurface, dict[str, Any]]:  # fmt: skip
    """The rollers' surfaces from their fine angles (rad, ``(n + 1, 4)``) at ``rate_hz`` with
    the true radii and every run-out (healthy and faulty), and the sidecar's record of them."""
    radius = {str(r.name): r.diameter_mm * 5e-4 for r in train.spec.roller}
    outs = run_outs(cfg, dist.roller_phase_rad, faults, ecc_phase)
    surface = roller_surface(angles, rate_hz, radius, outs,
                             [f for f in faults if f.kind == "flute"])  # fmt: skip
    return surface, surface_info(rate_hz, radius, outs, surface)


def _config_record(cfg: PlantConfig, *, surface: bool) -> dict[str, Any]:
    """The sidecar's plant configuration. The rollers' radius run-out acts only on the
    surfaces, so it is recorded only with them: sidecars without surfaces stay as they were
    before the setting existed."""
    if surface:
        return cfg.model_dump(mode="json")
    return cfg.model_dump(mode="json", exclude={"eccentricity": {"roller_eccentricity_um"}})


def _driven_train(
    train: DriveTrain, dist: Disturbances, faults: Sequence[FaultSpec], setpoint: Signal,
    t0: float, t1: float, rng: np.random.Generator,
    angles_at: dict[str, float] | None = None,
) -> tuple[DriveTrain, FaultSchedule | None, dict[str, float]]:  # fmt: skip
    """The true train with its inputs attached and the machine faults applied: time signals
    for the rotor resistance and roller run-out, a table schedule for the rest; and the phase
    (rad) of each roller eccentricity fault (roller name -> phase)."""
    rotor = [f for f in faults if f.kind == "rotor_resistance"]
    rotor_sig = (rotor_resistance_signal(dist.rotor_resistance, rotor, FORCE_GRID_S * 10)
                 if rotor else dist.rotor_resistance)  # fmt: skip
    driven = train.with_supply_schedule(dist.supply_hz).with_rotor_resistance(rotor_sig)
    for node, sig in dist.torques.items():
        driven = driven.with_torque(node, sig)
    ecc = [f for f in faults if f.kind == "eccentricity"]
    phases: dict[str, float] = {}
    if ecc:
        torques, phases = eccentricity_torques(train, ecc, setpoint, t0, t1, FORCE_GRID_S, rng,
                                               angles_at)  # fmt: skip
        for node, sig in torques.items():
            driven = driven.with_torque(node, sig)
    schedule = FaultSchedule(driven, faults)
    return driven, schedule if schedule.faults else None, phases


def _streams(seed: int) -> dict[str, np.random.Generator]:
    children = np.random.SeedSequence(seed).spawn(len(STREAMS))
    return {name: np.random.default_rng(c) for name, c in zip(STREAMS, children, strict=True)}
