"""``drafttwin plant serve``: the plant emulator as live machines over OPC UA or MQTT, with
its own log of every published sample (docs/twin.md)."""

from __future__ import annotations

import math
import signal
from pathlib import Path
from typing import Annotated, Any

import typer

from drafttwin.cli._exit import work_done
from drafttwin.cli._options import (
    LevellerFaultOpt,
    LevellerOpt,
    SampleRateOpt,
    StopAfterOpt,
    file_out,
    machine_name,
    number,
    path_in,
)
from drafttwin.cli.plant_cmds import FeedFaultOpt, FibreScaleOpt
from drafttwin.cli.twin_cmds import _need_twin_extra, plant_app
from drafttwin.cli.typer_app import console, err_console
from drafttwin.errors import ConfigError

OpcuaOpt = Annotated[str | None, typer.Option("--opcua", help="Serve over OPC UA at this address, e.g. opc.tcp://127.0.0.1:4840.")]  # fmt: skip
MqttOpt = Annotated[str | None, typer.Option("--mqtt", help="Publish to the MQTT broker at "
                    "HOST:PORT (one is started there if none answers and HOST is local).")]  # fmt: skip

NameOpt = Annotated[str, machine_name("--name", "Machine name (NAME-1, NAME-2... for several).")]
MachinesOpt = Annotated[int, number("--machines", "Number of machines.")]
SeedOpt = Annotated[int, number("--seed", "Seed of the first machine (+1 per machine).")]
PhysicsOpt = Annotated[str, typer.Option("--physics", help="full (the truth) | reduced (many machines).")]  # fmt: skip
RampOpt = Annotated[float, number("--ramp", "VFD ramp toward a new set-point, Hz/s.")]
MqttUserOpt = Annotated[str | None, typer.Option("--mqtt-user", help="MQTT: connect as this user "
                        "(password in DRAFTTWIN_MQTT_PASSWORD); the embedded broker admits only it.")]  # fmt: skip
CertOpt = Annotated[Path | None, path_in(
    "--cert", "Security with the certificates in this folder ('drafttwin twin certs'): OPC UA "
    "Basic256Sha256 SignAndEncrypt, trusted clients only; MQTT over TLS.")]  # fmt: skip
BrokerOpt = Annotated[str, typer.Option("--broker", help=(
    "MQTT: auto (start the embedded amqtt broker when none answers locally) | external (publish "
    "to the broker there, e.g. Mosquitto; never start one) | embedded."))]  # fmt: skip
HistoryOpt = Annotated[float, number("--history", "OPC UA: keep each machine's samples of the "
                       "last SECONDS for HistoryRead (in memory): a restarted twin recovers what "
                       "it missed.")]  # fmt: skip
ServeFaultOpt = Annotated[list[str] | None, typer.Option("--fault", help=(
    "Inject a fault into every served machine: ELEMENT:KIND:severity=S:onset=T[:ramp=R] (T, R "
    "in s from the start; the syntax of 'generate --fault', docs/faults.md). Not live: "
    "rotor_resistance, eccentricity."))]  # fmt: skip
QosOpt = Annotated[int, number("--qos", "MQTT: QoS of the samples, 0 (at most once) or 1 (at least once).")]  # fmt: skip
MaxLagOpt = Annotated[float | None, number(
    "--max-lag", "Behind the wall clock by more than SECONDS, skip samples to catch up (the "
    "counter jumps; a twin counts them as dropped). Default: publish every sample, late if need "
    "be; the lateness is logged, warned past 1 s and summed up either way.")]  # fmt: skip
LogOpt = Annotated[Path | None, file_out("--log", "Write every published sample to this "
                   ".parquet/.csv file when the plant stops (the plant's own record, for "
                   "'drafttwin twin audit'); with --sliver the sliver readings to "
                   "LOG.sliver.parquet/.csv beside it (for 'sliver level --data').")]  # fmt: skip
ServeSliverOpt = Annotated[bool, typer.Option("--sliver", help=(
    "Make sliver as the machines run (their true roller surfaces draft six card slivers, fibre "
    "by fibre) and publish the delivery and infeed sensors' readings and the store's length "
    "clock: OPC UA NAME/Sliver (arrays with units) and NAME/Leveller, MQTT "
    "drafttwin/NAME/sliver and drafttwin/NAME/leveller (docs/twin.md)."))]  # fmt: skip


@plant_app.command("serve")
def plant_serve(
    opcua: OpcuaOpt = None, mqtt: MqttOpt = None, name: NameOpt = "fa320a",
    machines: MachinesOpt = 1, seed: SeedOpt = 0, rate: SampleRateOpt = 100.0,
    physics: PhysicsOpt = "full", ramp: RampOpt = 10.0, duration: StopAfterOpt = None,
    mqtt_user: MqttUserOpt = None, cert: CertOpt = None, broker: BrokerOpt = "auto",
    history: HistoryOpt = 0.0, fault: ServeFaultOpt = None, qos: QosOpt = 0,
    max_lag: MaxLagOpt = None, log: LogOpt = None, sliver: ServeSliverOpt = False,
    leveller: LevellerOpt = None, leveller_fault: LevellerFaultOpt = None,
    feed_fault: FeedFaultOpt = None, fibre_scale: FibreScaleOpt = 1.0,
) -> None:  # fmt: skip
    """Run the plant emulator in real time as live machines: roller and motor speeds every
    sample, a writable supply set-point (write it and the plant changes speed); with
    --sliver the sliver sensors' readings too, through the machine's autoleveller where it
    has one (--leveller; its setting is published, never written from outside)."""
    _need_twin_extra()
    from drafttwin.plant.serve.pacing import Pacing
    from drafttwin.wire.plantlog import open_plant_log

    if broker not in ("auto", "external", "embedded"):
        raise ConfigError(f"unknown broker mode {broker!r}", where="--broker",
                          fix="use auto, external or embedded")  # fmt: skip
    if (opcua is None) == (mqtt is None):
        raise ConfigError("give one of --opcua and --mqtt", where="--opcua",
                          fix="e.g. --opcua opc.tcp://127.0.0.1:4840")  # fmt: skip
    if physics not in ("full", "reduced"):
        raise ConfigError(f"unknown physics {physics!r}", where="--physics",
                          fix="use full or reduced")  # fmt: skip
    if rate > 1000:
        raise ConfigError(f"--rate {rate:g}: a live plant publishes at most 1000 Hz",
                          where="--rate", fix="use --rate 100 (the FA320A logger's rate)")  # fmt: skip
    if history and opcua is None:
        raise ConfigError("--history is for OPC UA (MQTT keeps no history of QoS 0 samples)",
                          where="--history", fix="drop --history, or serve with --opcua")  # fmt: skip
    if qos and mqtt is None:
        raise ConfigError("--qos is for MQTT (OPC UA has no QoS)", where="--qos",
                          fix="drop --qos, or serve with --mqtt")  # fmt: skip
    if mqtt_user is not None and mqtt is None:  # it had run without a word, open to anyone
        raise ConfigError("--mqtt-user is for MQTT (an OPC UA server takes certificates: "
                          "--cert)", where="--mqtt-user",
                          fix="drop --mqtt-user, or serve with --mqtt")  # fmt: skip
    if log is not None and log.suffix.lower() not in (".parquet", ".csv"):
        raise ConfigError(f"unsupported log file type '{log.suffix or '(none)'}'", source=log,
                          where="--log", fix="name the log *.parquet or *.csv")  # fmt: skip
    from drafttwin.cli.plant_cmds import sliver_settings

    settings = sliver_settings(sliver, feed_fault, fibre_scale, leveller, leveller_fault)
    from drafttwin.mechanics import DriveTrain
    from drafttwin.plant.faults import FaultSpec
    from drafttwin.plant.live import live_faults

    faults = live_faults([FaultSpec.parse(f) for f in fault or []], DriveTrain.preset("fa320a"),
                         physics)  # fmt: skip
    names = [name] if machines == 1 else [f"{name}-{k + 1}" for k in range(machines)]
    opts: dict[str, Any] = {"seed": seed, "rate_hz": rate, "physics": physics,
                            "ramp_hz_per_s": ramp, "duration_s": duration, "faults": faults}  # fmt: skip
    pacing = Pacing(rate, max_lag_s=math.inf if max_lag is None else max_lag,
                    warn=lambda text: err_console.print(f"warning: {text}"))  # fmt: skip
    opts["pacing"] = pacing
    if qos:
        opts["qos"] = qos
    published = dict.fromkeys(names, 0)
    slivers: dict[str, Any] = {}
    with open_plant_log(log, sliver=settings is not None) as plant_log:

        def on_sample(machine: str, sample: Any) -> None:
            published[machine] += 1
            if plant_log is not None:
                plant_log.add(machine, sample)

        def on_sliver(live: Any, batch: Any) -> None:
            if live.name not in slivers:
                slivers[live.name] = live
                if plant_log is not None:
                    plant_log.describe(live.name, live.describe())
            if plant_log is not None:
                plant_log.add_sliver(batch)

        opts["on_sample"] = on_sample
        if settings is not None:
            opts.update(sliver=settings, on_sliver=on_sliver)
        if history:
            opts["history_s"] = history
        signum = _serve_plant(opcua, mqtt, names, opts, mqtt_user, cert, broker)
    work_done()  # the servers closed, the log written
    if signum is not None:
        err_console.print(f"stopped by {signal.Signals(signum).name}")
    console.print("published " + ", ".join(f"{k}: {v} samples" for k, v in published.items()))
    console.print(pacing.summary())
    for live in slivers.values():
        console.print("sliver " + live.summary())
    if log is not None:
        console.print(f"wrote {log}" + (f", {plant_log.sliver_path}" if slivers and plant_log
                                        and plant_log.sliver_path else "")
                      + (f", {plant_log.sidecar_path}" if plant_log
                         and plant_log.sidecar_written else ""))  # fmt: skip


def _serve_plant(opcua: str | None, mqtt: str | None, names: list[str], opts: dict[str, Any],
                 mqtt_user: str | None, cert: Path | None, broker: str) -> int | None:  # fmt: skip
    """Run the plant until its duration (then ``None``), Ctrl-C or SIGTERM (the signal's
    number): the signal cancels the serving task at its next ``await``, never inside a step
    of the physics, so the log is written and nothing is printed but the summary."""
    from drafttwin.twin.aio import run_until_signal

    if opcua is not None:
        from drafttwin.plant.serve.opcua import parse_opcua_url, serve_opcua

        parse_opcua_url(opcua)

        def ready() -> None:
            err_console.print(f"serving {', '.join(names)} on OPC UA {opcua}, nodes "
                              "ns=2;s=NAME.sample (Ctrl-C stops)")  # fmt: skip

        try:
            return run_until_signal(serve_opcua(opcua, names, ready=ready, cert_dir=cert, **opts))[
                1
            ]
        except OSError as exc:
            import errno

            fix = ("give an address of this machine (127.0.0.1, or one of its interfaces)"
                   if exc.errno == errno.EADDRNOTAVAIL else "choose a free port")  # fmt: skip
            raise ConfigError(f"cannot serve on {opcua} ({exc.strerror or exc})", where="--opcua",
                              fix=fix) from None  # fmt: skip
    else:
        from drafttwin.plant.serve.mqtt import serve_mqtt
        from drafttwin.wire.conventions import parse_hostport

        parse_hostport(str(mqtt), "--mqtt")

        def said(where: str) -> None:
            err_console.print(f"serving {', '.join(names)} on {where}, topics "
                              "drafttwin/NAME/sample (Ctrl-C stops)")  # fmt: skip

        try:
            return run_until_signal(serve_mqtt(str(mqtt), names, ready=said, username=mqtt_user,
                                               password=_mqtt_password(mqtt_user), cert_dir=cert,
                                               broker_mode=broker, **opts))[1]  # fmt: skip
        except OSError as exc:
            raise ConfigError(f"cannot reach or start a broker at {mqtt} ({exc.strerror or exc})",
                              where="--mqtt", fix="choose a free port or a running broker") from None  # fmt: skip


def _mqtt_password(user: str | None) -> str | None:
    import os

    if user is None:
        return None
    password = os.environ.get("DRAFTTWIN_MQTT_PASSWORD")
    if not password:
        raise ConfigError(f"no password for MQTT user {user!r}", where="--mqtt-user",
                          fix="set DRAFTTWIN_MQTT_PASSWORD (kept out of the command line)")  # fmt: skip
    return password
