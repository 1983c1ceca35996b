"""``drafttwin twin run | query`` and ``drafttwin plant serve``: the live twin (docs/twin.md)."""

from __future__ import annotations

import asyncio
import math
import signal
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.table import Table

from drafttwin.cli._exit import work_done
from drafttwin.cli._groups import stops_cleanly
from drafttwin.cli._options import JsonOpt, StopAfterOpt, dir_out, file_out, number, path_in
from drafttwin.cli.typer_app import app, console, err_console, print_json, print_table
from drafttwin.errors import ConfigError

if TYPE_CHECKING:
    from drafttwin.twin.publish.base import Publisher
    from drafttwin.twin.service import TwinService
    from drafttwin.twin.store.db import EventRow

twin_app = typer.Typer(
    help="The live twin: machines over OPC UA / MQTT or a replayed file, the hybrid per "
    "sample, a crash-safe history, a page (see docs/twin.md).",
    no_args_is_help=True,
)
app.add_typer(twin_app, name="twin")
plant_app = typer.Typer(
    help="The plant emulator as a live machine (see docs/twin.md).", no_args_is_help=True
)
app.add_typer(plant_app, name="plant")

# the options of the twin commands (twin_ops_cmds.py takes them too)
TwinModelOpt = Annotated[Path, path_in("--model", "Model file (.dtm) for the machines (a mapping may name others).")]  # fmt: skip
StoreReadOpt = Annotated[Path, path_in("--store", "Store folder a twin wrote.")]
MachineOpt = Annotated[str | None, typer.Option("--machine", help="One machine (default: all).")]
CommitMsOpt = Annotated[float, number("--commit-ms", "Commit interval, ms: a crash loses at most this much.")]  # fmt: skip
TwinPhysicsOpt = Annotated[str, typer.Option("--physics", help="reduced (fast) | full drive train.")]  # fmt: skip
TokenOpt = Annotated[str | None, typer.Option("--token", envvar="DRAFTTWIN_TOKEN",
                     help="Token every request must carry (required off 127.0.0.1).")]  # fmt: skip
TwinQuietOpt = Annotated[bool, typer.Option(help="No status line every 10 s on stderr (the events, alarms among them, are still printed as they happen).")]  # fmt: skip


def _need_twin_extra() -> None:
    import logging

    # asyncua and amqtt log every reconnect and closed channel; the twin reports them itself
    for name in ("asyncua", "amqtt", "transitions"):
        logging.getLogger(name).setLevel(logging.CRITICAL)
    try:
        import asyncua  # noqa: F401
        import duckdb  # noqa: F401
    except ImportError as exc:
        raise ConfigError(f"the live twin needs the 'twin' extra ({exc.name} is missing)",
                          fix="pip install 'drafttwin[twin]'") from None  # fmt: skip


def parse_bind(text: str, token: str | None) -> tuple[str, int]:
    """``HOST:PORT`` for the page; anything but 127.0.0.1 / localhost needs a token."""
    host, _, port_text = text.rpartition(":")
    try:
        port = int(port_text)
    except ValueError:
        port = -1
    if not host or not 0 <= port <= 65535:
        raise ConfigError(f"bad address {text!r}", where="--http",
                          fix="write HOST:PORT, e.g. 127.0.0.1:8050")  # fmt: skip
    if host not in ("127.0.0.1", "localhost", "::1") and not token:
        raise ConfigError(f"refusing to serve the page on {host} without a token", where="--http",
                          fix="bind 127.0.0.1, or pass --token (or DRAFTTWIN_TOKEN) so every "
                          "request must carry it")  # fmt: skip
    if token is not None and len(token) < 16:
        raise ConfigError("the token is shorter than 16 characters", where="--token",
                          fix="use a long random token, e.g. python -c 'import secrets; "
                          "print(secrets.token_urlsafe())'")  # fmt: skip
    return host, port


SourcesOpt = Annotated[list[str], typer.Option("--source", help="replay:FILE?speed=10&machine=NAME "
                      "| opcua:opc.tcp://HOST:PORT | mqtt://HOST:PORT; repeat for several "
                      "sources.")]  # fmt: skip
MappingOpt = Annotated[Path | None, path_in("--mapping", "Mapping TOML: machines, their nodes/topics, fields, models.")]  # fmt: skip
StoreOpt = Annotated[Path | None, dir_out("--store", "Store folder (DuckDB): every sample, prediction, residual, event.")]  # fmt: skip
RetentionOpt = Annotated[float | None, number("--retention-hours", "Keep this many hours per machine (default: all).")]  # fmt: skip
HttpOpt = Annotated[str | None, typer.Option("--http", help="Serve the page, REST API and /metrics on HOST:PORT.")]  # fmt: skip
PublishOpt = Annotated[list[str] | None, typer.Option("--publish", help="Publish predictions, "
                       "residuals, health and alarms: opcua:opc.tcp://HOST:PORT[?hz=10] (the "
                       "twin's own OPC UA server) | mqtt://HOST:PORT[?qos=1&hz=10&prefix="
                       "drafttwin/twin]; hz: predictions per machine and second; repeatable "
                       "(docs/twin.md).")]  # fmt: skip
DetectorOpt = Annotated[str, typer.Option("--detector", help=(
    "Fault detection: auto (each machine learns its healthy state, on top of "
    "MODEL.dtm.detector.json from 'twin fit-detector' when it exists; a baseline it learned "
    "before is read back from --store) | none | FILE (the detector file to learn on top of). "
    "Alarms with their probable cause go to the store, the page, /api/alarms, /metrics and "
    "--publish."))]  # fmt: skip
LearnOpt = Annotated[float | None, number("--learn", (
    "Seconds of running a machine new to the twin learns before it is watched (no fault "
    "alarm meanwhile). Default: what the detector needs: 600 alone, 120 on top of a detector "
    "file that watches the angle lags. 0: no learning, the detector file judges every "
    "machine as it is (one fitted on another machine is flagged)."))]  # fmt: skip
SilentOpt = Annotated[float, number("--silent", "A machine silent this long (s) is marked as a gap.")]  # fmt: skip
LevelWindowOpt = Annotated[float, number("--level-window", (
    "Metres of delivered sliver per recommendation of the leveller's action point (a source "
    "with the sliver sensors and the leveller's setting: plant serve --sliver, a replayed "
    "record made with --sliver): 'sliver level' on each window, never a setting written."))]  # fmt: skip
LevelSearchOpt = Annotated[float, number("--level-search", "Action points searched either side of each machine's leveller setting for its recommendation, mm (as 'sliver level --search'; a window whose least CV lies on the edge recommends nothing and asks for more).")]  # fmt: skip
MaxSamplesOpt = Annotated[int | None, number("--max-samples", "Stop after this many processed samples.")]  # fmt: skip
# derived from the parameter's name, as --verbose/--no-verbose
VerboseOpt = Annotated[bool, typer.Option(help="A line per store commit.")]
StatusJsonOpt = Annotated[bool, typer.Option("--json", help="Print the final status as JSON.")]


@twin_app.command("run")
def twin_run(
    model: TwinModelOpt, source: SourcesOpt, mapping: MappingOpt = None,
    store: StoreOpt = None, commit_ms: CommitMsOpt = 200.0, retention_hours: RetentionOpt = None,
    http: HttpOpt = None, token: TokenOpt = None, physics: TwinPhysicsOpt = "reduced",
    publish: PublishOpt = None, detector: DetectorOpt = "auto", learn: LearnOpt = None,
    silent: SilentOpt = 2.0, level_window: LevelWindowOpt = 300.0,
    level_search: LevelSearchOpt = 120.0,
    duration: StopAfterOpt = None, max_samples: MaxSamplesOpt = None,
    verbose: VerboseOpt = False, quiet: TwinQuietOpt = False, as_json: StatusJsonOpt = False,
) -> None:  # fmt: skip
    """Run the live twin: per sample, the paper's causal cleaning, the physics following the
    set-point, the model through one incremental predictor; store and serve the result. A
    source with a sliver channel is watched (count, CV, spectrogram, chimneys) and its
    leveller's action point recommended every --level-window metres.
    Stops when every source ended (a replay), after --duration or --max-samples, or on Ctrl-C."""
    _need_twin_extra()
    from drafttwin.execution.interrupt import stop_on_signals

    with stop_on_signals("while starting; nothing was stored"):  # until the twin's own handler
        import torch

        from drafttwin.twin.build import build_service
        from drafttwin.twin.publish import parse_publish

        torch.set_num_threads(1)  # one window per sample: threads cost more than they give
        if physics not in ("reduced", "full"):
            raise ConfigError(f"unknown physics {physics!r}", where="--physics",
                              fix="use reduced or full")  # fmt: skip
        bind = None if http is None else parse_bind(http, token)
        publishers = [parse_publish(text) for text in publish or []]

        def on_commit(rows: int, last_ts_us: int) -> None:
            if verbose:  # called by the writer thread just after the commit, with its duration
                took = service.writer.commit_seconds[-1] * 1e3 if service.writer else math.nan
                # last_ts_us stays the last field: scripts that cut the line after it still work
                print(f"commit rows={rows} ms={took:.1f} at={time.time():.3f} "
                      f"last_ts_us={last_ts_us}", flush=True)  # fmt: skip

        service = build_service(model, source, mapping=mapping, store_dir=store, commit_ms=commit_ms,
                                retention_s=None if retention_hours is None else retention_hours * 3600,
                                physics=physics, silent_s=silent, on_commit=on_commit,
                                detector=detector, learn_s=learn,
                                level_window_m=level_window, level_search_mm=level_search)  # fmt: skip
    start = time.monotonic()
    try:
        from drafttwin.twin.aio import run_until_signal

        # SIGTERM ends the twin like Ctrl-C: what was received is committed; only SIGKILL
        # loses the rows of the open commit interval
        _, signum = run_until_signal(_serve(service, bind, token, duration, max_samples, quiet,
                                            publishers))  # fmt: skip
        if signum is not None:
            err_console.print(f"stopped by {signal.Signals(signum).name}: committing what "
                              "was received")  # fmt: skip
    except OSError as exc:
        raise ConfigError(f"cannot serve the page on {http} ({exc.strerror or exc})",
                          where="--http", fix="choose a free port") from None  # fmt: skip
    finally:
        if service.writer is not None:
            service.writer.close()
            service.writer.store.close()
    work_done()  # the store closed: the summary below is all that is left
    status = service.status()
    status["wall_s"] = time.monotonic() - start
    if publishers:
        status["publish"] = [pub.summary() for pub in publishers]
    if as_json:
        print_json(status)
        return
    _print_status(status)


async def _serve(service: TwinService, bind: tuple[str, int] | None, token: str | None,
                 duration: float | None, max_samples: int | None, quiet: bool,
                 publishers: Sequence[Publisher] = ()) -> None:  # fmt: skip
    from drafttwin.twin.publish import publishing

    ticker = None if quiet else asyncio.create_task(_status_lines(service))
    # alarms, causes and the detector's learning as they happen, --quiet or not (a twin under
    # a service manager logs them; --quiet left only its last lines there)
    for st in service.states.values():  # what the detector said while the twin was built
        for ev in st.events:
            if ev.kind in ("baseline", "baseline-refused", "learning", "detector-foreign"):
                _print_event(ev)
    service.event_hooks.append(_print_event)
    try:
        async with publishing(service, publishers):
            for pub in publishers:
                err_console.print(f"publishing on {pub.spec}")
            if bind is None:
                await service.run(duration_s=duration, max_rows=max_samples)
                return
            from drafttwin.twin.web.server import serve_with

            def started(_: object) -> None:
                err_console.print(f"page on http://{bind[0]}:{bind[1]}/")

            await serve_with(service, bind, token, duration, max_samples, started)
    finally:
        if ticker is not None:
            ticker.cancel()


def _print_event(ev: EventRow) -> None:
    from drafttwin.twin.alarms import event_line

    line = event_line(ev.machine, ev.kind, ev.ts_us, ev.detail)
    if line is not None:
        err_console.print(line, highlight=False, markup=False, soft_wrap=True)


async def _status_lines(service: TwinService) -> None:
    """One line every 10 s: samples, p99 latency, machines by state (a live run has no end
    to show a progress bar against)."""
    while True:
        await asyncio.sleep(10.0)
        status = service.status()
        states: dict[str, int] = {}
        for m in status["machines"].values():
            states[m["state"]] = states.get(m["state"], 0) + 1
        p99 = status["latency_ms"]["p99"]
        err_console.print(f"{status['rows']} samples, p99 {'-' if p99 is None else f'{p99:.1f}'} "
                          "ms, machines " + ", ".join(f"{v} {k}" for k, v in states.items()),
                          highlight=False)  # fmt: skip


_OFF_CLOCK_MS = 3.6e6
"""A source whose times lie more than an hour off the wall clock is not stamping live samples
(``plant replay`` of records from 2023, a machine with its clock unset)."""


def _print_status(status: dict[str, Any]) -> None:
    table = Table(title=f"live twin: {status['rows']} samples in {status['wall_s']:.1f} s")
    for col in ("machine", "state", "received", "processed", "dropped", "late", "duplicate",
                "skipped", "spikes"):  # fmt: skip
        table.add_column(col, justify="left" if col in ("machine", "state") else "right")
    for name, m in status["machines"].items():
        table.add_row(name, m["state"], str(m["received"]), str(m["processed"]), str(m["dropped"]),
                      str(m["late"]), str(m["duplicate"]), str(m["skipped"]),
                      str(m["spikes_rejected"]))  # fmt: skip
    print_table(table)
    lat = status["latency_ms"]
    if lat["p99"] is not None:
        console.print(f"latency received -> stored/pushed: p50 {lat['p50']:.2f} ms, "
                      f"p99 {lat['p99']:.2f} ms, max {lat['max']:.2f} ms")  # fmt: skip
    for name, m in status["machines"].items():
        if m.get("transport_ms") is not None:  # live sources: the source stamps each sample
            tr = m["transport_ms"]
            if abs(tr["p50"]) > _OFF_CLOCK_MS:  # a replay of old records, a source's clock off
                console.print(f"{name}: the source's times are {tr['p50'] / 3.6e6:+.1f} h off "
                              f"the wall clock (a replay?): no transport figure")  # fmt: skip
                continue
            console.print(f"{name}: source -> received (transport and the source's own "
                          f"lateness): p50 {tr['p50']:.1f} ms, p99 {tr['p99']:.1f} ms")  # fmt: skip
    for name, m in status["machines"].items():
        for a in m.get("active_alarms") or []:
            from drafttwin.twin.alarms import cause_text

            state = "active" if a["active"] else "returned to normal"
            ack = ("acknowledged" if a["acked"] else "not acknowledged") + (
                ", confirmed" if a.get("confirmed") else "")  # fmt: skip
            console.print(f"{name}: alarm {a['test']} ({state}, {ack}): "
                          f"{cause_text(a.get('cause'))}", highlight=False, markup=False, soft_wrap=True)  # fmt: skip
    for name, m in status["machines"].items():
        _print_sliver(name, m)
    if status["store"] is not None:
        console.print(f"store: {status['store']['committed']} rows committed")
    for pub in status.get("publish", []):
        console.print(f"published on {pub['spec']}: {pub['sent']} sent, {pub['dropped']} "
                      f"dropped, {pub['failed']} failed")  # fmt: skip


def _print_sliver(name: str, m: dict[str, Any]) -> None:
    """The machine's sliver and its leveller's standing recommendation, if it has them."""
    s, lev = m.get("sliver"), m.get("leveller")
    if s is not None:
        chimneys = ", ".join(f"{100 * c['wavelength_m']:.2f} cm ({c['element']})"
                             for c in s["chimneys"]) or "none"  # fmt: skip
        lim = s.get("count_limit")
        held = "" if lim is None else (
            f", count OFF its +-{lim['limit_pct']:g} % limit now" if lim["outside"]
            else f", count within +-{lim['limit_pct']:g} % ({lim['excursions']} excursion(s))")  # fmt: skip
        console.print(f"{name}: sliver {s['delivered_m']:.1f} m, count {s['count_ktex']:.4f} ktex"
                      f"{held}, CV {s['cv_pct']:.3f} %, {s['alarms']} chimney alarm(s); chimneys "
                      f"in the last spectrogram: {chimneys}", highlight=False)  # fmt: skip
    a = None if lev is None else lev["advice"]
    if lev is not None and a is not None and lev["state"] != "recommending":
        console.print(f"{name}: {lev['says']} (last of {lev['checks']} windows of "
                      f"{lev['window_m']:g} m)", highlight=False)  # fmt: skip
    elif lev is not None and a is None:
        console.print(f"{name}: leveller {lev['state']}, {lev['collected_m']:.0f} of "
                      f"{lev['window_m']:g} m" + (f" ({lev['failed']})" if lev["failed"] else ""),
                      highlight=False)  # fmt: skip
    elif a is not None and lev is not None:
        lo, hi = a["action_point_interval_mm"]
        now = a["current_action_point_mm"]
        console.print(f"{name}: leveller action point {a['recommended_action_point_mm']:.1f} mm "
                      f"(95 % {lo:.1f}-{hi:.1f}), intensity {a['recommended_intensity']:.2f} "
                      f"recommended; current {'none' if now is None else f'{now:.1f} mm'}: CV "
                      f"{a['current']['cv_pct']:.3f} % -> {a['recommended']['cv_pct']:.3f} % "
                      f"expected (last of {lev['checks']} windows of {lev['window_m']:g} m; "
                      "the twin writes no setting)", highlight=False)  # fmt: skip


FromOpt = Annotated[float | None, number("--from", "From this time, s (inclusive).")]
ToOpt = Annotated[float | None, number("--to", "To this time, s (inclusive).")]
SamplesOutOpt = Annotated[Path | None, file_out("--out", "Write the samples to a .csv or .parquet file.")]  # fmt: skip
# derived from the parameter's name, as --events/--no-events
EventsOpt = Annotated[bool, typer.Option(help="Export the events instead of samples.")]


@twin_app.command("query")
@stops_cleanly("nothing was written")
def twin_query(
    store: StoreReadOpt,
    machine: MachineOpt = None,
    t_from: FromOpt = None,
    t_to: ToOpt = None,
    out: SamplesOutOpt = None,
    events: EventsOpt = False,
    as_json: JsonOpt = False,
) -> None:
    """Export a twin's history (all of it by default): per sample the measured values, the
    physics, the twin's prediction and the residual per channel; or its events."""
    _need_twin_extra()
    from drafttwin.cli._common import check_output_suffix, write_frame
    from drafttwin.twin.store.history import read_events, read_history, summary

    if out is not None:
        check_output_suffix(out)
    if t_from is not None and t_to is not None and t_to < t_from:
        raise ConfigError(f"--to {t_to:g} is before --from {t_from:g}", where="--to",
                          fix="give --from <= --to")  # fmt: skip
    if events:
        frame = read_events(store, machine, t_from, t_to)
    else:
        frame = read_history(store, machine, t_from, t_to)
    if out is not None:
        write_frame(frame, out)
    machines = summary(store)
    if as_json:
        print_json({"rows": len(frame), "out": None if out is None else str(out),
                    "machines": machines})  # fmt: skip
        return
    table = Table(title=f"twin store {store}")
    for col in ("machine", "samples", "first s", "last s", "events"):
        table.add_column(col, justify="left" if col == "machine" else "right")
    for m in machines:
        table.add_row(str(m["machine"]), str(m["samples"]), _t(m["first_s"]), _t(m["last_s"]),
                      str(m["events"]))  # fmt: skip
    console.print(table)
    console.print(f"{len(frame)} {'events' if events else 'samples'} selected"
                  + (f", wrote {out}" if out is not None else ""))  # fmt: skip


def _t(x: object) -> str:
    return f"{x:.3f}" if isinstance(x, float) and math.isfinite(x) else "-"


CertsOutOpt = Annotated[Path, dir_out("--out", "Folder for the keys and certificates.")]
HostOpt = Annotated[str, typer.Option("--host", help="Host name in the certificates.")]


@twin_app.command("certs")
def twin_certs(out: CertsOutOpt, host: HostOpt = "127.0.0.1") -> None:
    """Make self-signed OPC UA certificates and an MQTT TLS certificate (365 days) for 'plant
    serve --cert' and the twin's sources 'opcua:URL?cert=DIR' and 'mqtts://HOST:PORT?cert=DIR'.
    Those still valid for --host are kept (and listed as kept); keys are owner-only (0600)."""
    _need_twin_extra()
    from drafttwin.twin.sources.security import make_certificates

    written, kept = asyncio.run(make_certificates(out, host))
    if written:
        console.print("wrote " + ", ".join(str(p) for p in written) + f" and {out / 'trusted'}")
    if kept:
        console.print("kept (still valid for " + host + "): " + ", ".join(p.name for p in kept))
