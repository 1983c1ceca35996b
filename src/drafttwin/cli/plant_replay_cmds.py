"""``drafttwin plant replay``: recorded files served as live machines over MQTT, faster than
the wall clock if asked (docs/twin.md, "Replaying records live")."""

from __future__ import annotations

import signal
from pathlib import Path
from typing import Annotated

import typer

from drafttwin.cli._options import ColumnsOpt, file_in, file_out, files_in, machine_name, number
from drafttwin.cli.twin_cmds import _need_twin_extra, plant_app
from drafttwin.cli.typer_app import console, err_console
from drafttwin.errors import ConfigError

RecordsOpt = Annotated[str | None, files_in("--records", (
    "Recorded files (.parquet/.csv with the four rollers, the motor and supply_hz, as "
    "'drafttwin generate' or the fault benchmark wrote them), comma-separated; played in "
    "this order, dealt to the machines."))]  # fmt: skip
PlaylistOpt = Annotated[Path | None, file_in("--playlist", (
    'Instead of --records: a JSON file {"machines": {"NAME": ["a.parquet", ...]}} saying which '
    "machine plays which files in which order (paths relative to it)."))]  # fmt: skip
LeadOpt = Annotated[float, number("--lead", "Seconds to wait after connecting before the first sample (a twin subscribes meanwhile).")]  # fmt: skip
HoldOpt = Annotated[bool, typer.Option("--hold", help="Once played, keep the connections (and an "
                    "embedded broker) until SIGTERM, so a slower subscriber drains the queue.")]  # fmt: skip
ReplayMqttOpt = Annotated[str, typer.Option("--mqtt", help="The MQTT broker at HOST:PORT (one "
                          "is started there if none answers and HOST is local).")]  # fmt: skip
ReplayNameOpt = Annotated[
    str, machine_name("--name", "Machine name (NAME-1, NAME-2... for several).")
]
ReplayMachinesOpt = Annotated[int, number("--machines", "Machines served at once; the files are "
                              "dealt to them, each to the one with the least running so far.")]  # fmt: skip
SpeedOpt = Annotated[float, number("--speed", "Times real time.")]
BatchOpt = Annotated[int, number("--batch", "Samples per message on drafttwin/NAME/samples.")]
GapOpt = Annotated[float, number("--gap", "Seconds of silence between two files of a machine (a stop).")]  # fmt: skip
ManifestOpt = Annotated[Path | None, file_out("--manifest", "Write which file each machine "
                        "played when (source times) to this JSON file.")]  # fmt: skip
ReplayBrokerOpt = Annotated[str, typer.Option("--broker", help="auto | external | embedded (as 'plant serve').")]  # fmt: skip


@plant_app.command("replay")
def plant_replay(
    mqtt: ReplayMqttOpt, records: RecordsOpt = None, playlist: PlaylistOpt = None,
    name: ReplayNameOpt = "replay", machines: ReplayMachinesOpt = 1, speed: SpeedOpt = 1.0,
    batch: BatchOpt = 20, gap: GapOpt = 10.0, manifest: ManifestOpt = None,
    broker: ReplayBrokerOpt = "auto", lead: LeadOpt = 0.0, hold: HoldOpt = False,
    columns: ColumnsOpt = None,
) -> None:  # fmt: skip
    """Serve recorded files as live machines over MQTT: each machine plays its files one after
    another on its own clock (a gap between two is a stop), tells who each file's machine is
    (retained identification, from its sidecar), and sends its samples in batches at --speed
    times real time. A twin watches them as live machines ('twin run --source mqtt://...');
    'benchmark faults --live' serves the fault benchmark's records this way."""
    _need_twin_extra()
    from drafttwin._io import atomic_path
    from drafttwin._json import dumps_strict
    from drafttwin.cli._data import pairs
    from drafttwin.plant.serve.replay import (
        Entry,
        Slot,
        deal,
        manifest_of,
        read_rows,
        replay_mqtt,
    )
    from drafttwin.plant.serve.replay import playlist as read_playlist
    from drafttwin.twin.aio import run_until_signal

    # files of other column names (the reader's own error asks for --columns)
    mapped = pairs(columns, "--columns", "v1=front,v2=second") or None
    if broker not in ("auto", "external", "embedded"):
        raise ConfigError(f"unknown broker mode {broker!r}", where="--broker",
                          fix="use auto, external or embedded")  # fmt: skip
    if (records is None) == (playlist is None):
        raise ConfigError("give one of --records and --playlist", where="--records",
                          fix="e.g. --records a.parquet,b.parquet")  # fmt: skip
    if playlist is not None:
        slots = read_playlist(playlist)
        for s in slots:  # every file checked before anything is served
            for e in s.entries:
                read_rows(e.path, mapped)
        n_files = sum(len(s.entries) for s in slots)
    else:
        assert records is not None
        files = [Path(p.strip()) for p in records.split(",") if p.strip()]
        if not files:
            raise ConfigError("no record", where="--records", fix="give one or more files")
        durations = []
        for p in files:  # every file checked before anything is served
            t, _, _ = read_rows(p, mapped)
            durations.append(float(t[-1] - t[0]) if len(t) > 1 else 0.0)
        slots = deal(files, name, machines, durations)
        n_files = len(files)

    def said(slot: Slot, entry: Entry) -> None:
        err_console.print(f"{slot.name}: played {entry.path.name}")

    written: list[Path] = []

    def done() -> None:
        if manifest is not None:  # written as soon as everything is out (--hold waits on)
            with atomic_path(manifest) as tmp:
                tmp.write_text(dumps_strict(manifest_of(slots, speed, gap)), encoding="utf-8")
            written.append(manifest)
        err_console.print("played every file" + (" (holding until SIGTERM)" if hold else ""))

    err_console.print(f"replaying {n_files} file(s) on {len(slots)} machine(s) at "
                      f"{speed:g}x to MQTT {mqtt}")  # fmt: skip
    _, signum = run_until_signal(replay_mqtt(mqtt, slots, speed=speed, batch=batch, gap_s=gap,
                                             broker_mode=broker, lead_s=lead, hold=hold,
                                             on_entry=said, on_done=done, columns=mapped))  # fmt: skip
    if signum is not None:
        err_console.print(f"stopped by {signal.Signals(signum).name}")
    if written:
        console.print(f"wrote {manifest}")
    elif manifest is not None:  # stopped before every file was out: an older one is not this run's
        err_console.print(f"{manifest} not written: the replay stopped before every file was "
                          "played" + (" (the file there is an earlier run's)" if manifest.exists() else ""))  # fmt: skip
    console.print("published " + ", ".join(f"{s.name}: {s.published} samples" for s in slots))
