"""``drafttwin twin audit``: a twin's store counted against the plant's own log; ``drafttwin
twin hall``: a hall of machines spread over Ray actors (docs/twin.md)."""

from __future__ import annotations

import contextlib
import datetime as dt
import signal
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Annotated, Any

import typer
from rich import box
from rich.table import Table

from drafttwin.cli._exit import work_done
from drafttwin.cli._groups import stops_cleanly
from drafttwin.cli._options import JsonOpt, StopAfterOpt, dir_out, files_in, number, path_in
from drafttwin.cli.twin_cmds import (
    CommitMsOpt,
    LearnOpt,
    LevelSearchOpt,
    LevelWindowOpt,
    MachineOpt,
    StoreReadOpt,
    TokenOpt,
    TwinModelOpt,
    TwinPhysicsOpt,
    TwinQuietOpt,
    _need_twin_extra,
    parse_bind,
    twin_app,
)
from drafttwin.cli.typer_app import console, err_console, print_json, print_table
from drafttwin.errors import ConfigError, DrafttwinError
from drafttwin.execution.interrupt import Interrupted, stop_on_signals

RUNS_SHOWN = 10
"""Runs of absent samples listed per machine (the JSON has them all)."""


PlantLogOpt = Annotated[str, files_in("--plant-log", "The plant's log ('drafttwin plant serve --log FILE'); several, comma-separated: the logs of a plant's runs, or of several plants.")]  # fmt: skip


@twin_app.command("audit")
@stops_cleanly("nothing was written")
def twin_audit(
    store: StoreReadOpt,
    plant_log: PlantLogOpt,
    machine: MachineOpt = None,
    as_json: JsonOpt = False,
) -> None:
    """Count the store against the plant's log: per machine the samples published, stored,
    stored twice, stored with other values, and the runs of published samples the store lacks
    (with when the plant published them), apart from those before the twin's first and after
    its last stored sample."""
    _need_twin_extra()
    from drafttwin.twin.store.audit import as_json as audit_json
    from drafttwin.twin.store.audit import audit

    logs = [Path(p.strip()) for p in plant_log.split(",") if p.strip()]
    result = audit(store, logs, machine)
    if as_json:
        print_json({"machines": audit_json(result)})
        return
    several = len(logs) > 1
    table = Table(title=f"store {store} against {', '.join(map(str, logs))}", box=box.SIMPLE)
    cols = ("machine", *(("log",) if several else ()), "sent", "stored", "twice", "differ",
            "absent", "before", "after", "filled", "outside")  # fmt: skip
    for col in cols:
        table.add_column(col, justify="left" if col in ("machine", "log") else "right")
    for m in result:
        table.add_row(m.machine, *((Path(m.log).name,) if several else ()),
                      *map(str, (m.published, m.stored, m.duplicates, m.mismatched,
                                 m.missing_inside, m.before_first, m.after_last, m.filled,
                                 m.outside)))  # fmt: skip
    print_table(table)
    console.print("sent: published by the plant; twice: stored more than once; differ: stored with another time or value; "
                  "absent: published between the first and last stored sample but not stored "
                  "(runs below); before / after: published before the first / after the last "
                  "stored sample; filled: rows the twin made up for samples it never received; outside: "
                  "stored rows outside every given log's time span (another run of the plant, which "
                  "counts from 0 again: give that run's log too)",
                  highlight=False)  # fmt: skip
    for m in result:
        for r in m.runs[:RUNS_SHOWN]:
            console.print(f"{m.machine}: absent seq {r.first_seq}-{r.last_seq} ({r.samples} "
                          f"sample{'s' if r.samples > 1 else ''}), published "
                          f"{_clock(r.first_published_s)} to {_clock(r.last_published_s)}",
                          highlight=False)  # fmt: skip
        if len(m.runs) > RUNS_SHOWN:
            console.print(f"{m.machine}: {len(m.runs) - RUNS_SHOWN} more runs (--json lists "
                          "them all)", highlight=False)  # fmt: skip


def _clock(t: float) -> str:
    return dt.datetime.fromtimestamp(t, tz=dt.UTC).strftime("%H:%M:%S.%f")[:-3] + " UTC"


HallServerOpt = Annotated[str, typer.Option("--source", help="The hall's server: opcua:opc.tcp://HOST:PORT | mqtt://HOST:PORT.")]  # fmt: skip
HallMappingOpt = Annotated[Path, path_in("--mapping", "Mapping TOML listing the hall's machines (split over the shards).")]  # fmt: skip
HallDetectorOpt = Annotated[str, typer.Option("--detector", help=(
    "Fault detection: auto (each machine learns its healthy state, on top of "
    "MODEL.dtm.detector.json from 'twin fit-detector' when it exists) | none | FILE (the "
    "detector file to learn on top of). Alarms with their probable cause go to each shard's "
    "store and the hall page's alarm column."))]  # fmt: skip
ShardStoreOpt = Annotated[Path, dir_out("--store", "Store folder: one DuckDB file per shard (shard-I-of-K/).")]  # fmt: skip
ShardsOpt = Annotated[int, number("--shards", "Number of twins (Ray actors), K.")]
RayOpt = Annotated[str | None, typer.Option("--ray", help="Ray cluster address (HOST:PORT, "
                   "ray://HOST:PORT or auto); default: a private Ray on this machine with K CPUs.")]  # fmt: skip
HallHttpOpt = Annotated[str | None, typer.Option("--http", help=(
    "Serve the hall's page on HOST:PORT: every shard's machines at a glance (state, samples, "
    "fault alarms and their probable cause), refreshed every second."))]  # fmt: skip
ShardsJsonOpt = Annotated[bool, typer.Option("--json", help="Print each shard's status as JSON.")]


@twin_app.command("hall")
def twin_hall(
    model: TwinModelOpt, source: HallServerOpt, mapping: HallMappingOpt, store: ShardStoreOpt,
    shards: ShardsOpt = 2, ray_address: RayOpt = None, commit_ms: CommitMsOpt = 200.0,
    physics: TwinPhysicsOpt = "reduced", duration: StopAfterOpt = None,
    quiet: TwinQuietOpt = False, http: HallHttpOpt = None, token: TokenOpt = None,
    as_json: ShardsJsonOpt = False, detector: HallDetectorOpt = "auto", learn: LearnOpt = None,
    level_window: LevelWindowOpt = 300.0,
    level_search: LevelSearchOpt = 120.0,
) -> None:  # fmt: skip
    """Run a hall as K live twins, one Ray actor each: shard I takes the mapping's machines
    I, I+K, I+2K... (each machine whole in one twin) and writes its own store in
    STORE/shard-I-of-K/; 'twin query' and 'twin audit' read them all. Stops after --duration
    or on Ctrl-C / SIGTERM (every shard commits what it received)."""
    _need_twin_extra()
    from drafttwin.execution.executor import _check_address, _import_ray
    from drafttwin.twin.hall import ConsoleFollower, check_hall, check_store, run_hall

    if physics not in ("reduced", "full"):
        raise ConfigError(f"unknown physics {physics!r}", where="--physics",
                          fix="use reduced or full")  # fmt: skip
    bind = None if http is None else parse_bind(http, token)
    check_store(store, shards)
    n = check_hall(model, source, mapping, shards)
    _import_ray()
    if ray_address is not None:
        try:
            _check_address(ray_address)
        except DrafttwinError as exc:  # named after this command's option
            raise ConfigError(exc.problem, where="--ray", fix=exc.fix) from None
    err_console.print(f"hall: {n} machines over {shards} twins on "
                      f"{ray_address or 'a private Ray'}")  # fmt: skip

    from drafttwin.twin.web.hall import HallServer, HallView

    view = HallView(shards)
    printed = [0.0]
    follower = ConsoleFollower()

    def status(shard_status: list[dict[str, Any] | None]) -> None:  # the page's, a line per 10 s
        view.update(shard_status)
        for line in follower.new_lines(shard_status):  # the shards' events, as twin run's
            err_console.print(line, highlight=False, markup=False, soft_wrap=True)
        if quiet or time.monotonic() - printed[0] < 10.0:
            return
        printed[0] = time.monotonic()
        parts = []
        for i, st in enumerate(shard_status):
            if st is None or "rows" not in st:
                parts.append(f"shard {i}: {'starting' if st is None else st['state']}")
            else:
                p99 = st["latency_ms"]["p99"]
                parts.append(f"shard {i}: {st['state']}, {len(st['machines'])} machine(s), "
                             f"{st['rows']} samples, p99 {'-' if p99 is None else f'{p99:.1f}'} ms")  # fmt: skip
        err_console.print("; ".join(parts), highlight=False)

    start = time.monotonic()
    try:
        # Ray prints its own notes (a shard's process died and is started again) on stdout:
        # they go to stderr, so that stdout holds only the result (strict JSON with --json)
        with contextlib.ExitStack() as stack:
            stack.enter_context(stop_on_signals("the running shards committed what they received"))
            stack.enter_context(contextlib.redirect_stdout(sys.stderr))
            if bind is not None:
                try:
                    stack.enter_context(HallServer(view, bind, token))
                except OSError as exc:
                    raise ConfigError(f"cannot serve the hall page on {http} "
                                      f"({exc.strerror or exc})", where="--http",
                                      fix="choose a free port") from None  # fmt: skip
                err_console.print(f"hall page on http://{bind[0]}:{bind[1]}/")
            results = run_hall(model, source, mapping, store, shards, address=ray_address,
                               commit_ms=commit_ms, physics=physics, duration_s=duration,
                               on_status=status, on_actors=view.bind_commands,
                               status_every_s=1.0, detector=detector,
                               learn_s=learn, level_window_m=level_window,
                               level_search_mm=level_search)  # fmt: skip
    except Interrupted as exc:  # a service manager's stop is a clean end: exit code 0
        work_done()
        note = str(exc).partition("; ")[2]  # what the hall did, shard by shard
        err_console.print(f"stopped by {signal.Signals(exc.signum).name}: {note}", highlight=False)
        # a hall runs until it is stopped: its summary is what it did (it had printed none)
        _print_hall(getattr(exc, "results", []), shards, time.monotonic() - start, as_json)
        return
    work_done()  # Ray ended, the shards' stores closed
    _print_hall(results, shards, time.monotonic() - start, as_json)


def _print_hall(results: Sequence[dict[str, Any] | None], shards: int, wall_s: float,
                as_json: bool) -> None:  # fmt: skip
    """The hall's summary, a row per shard (None: a shard ended while it started)."""
    if as_json:
        print_json({"wall_s": wall_s, "shards": results})
        return
    table = Table(title=f"hall: {shards} twins, {wall_s:.1f} s", box=box.SIMPLE)
    for col in ("shard", "machines", "processed", "dropped", "p99 ms", "committed"):
        table.add_column(col, justify="left" if col in ("shard", "machines") else "right")
    for i, r in enumerate(results):
        if r is None:
            table.add_row(str(i), "(ended by the stop: see above)", "-", "-", "-", "-")
            continue
        p99 = r["latency_ms"]["p99"]
        table.add_row(str(i), ", ".join(r["machines"]),
                      str(sum(m["processed"] for m in r["machines"].values())),
                      str(sum(m["dropped"] for m in r["machines"].values())),
                      "-" if p99 is None else f"{p99:.1f}",
                      str(r["store"]["committed"]))  # fmt: skip
    console.print(table)
