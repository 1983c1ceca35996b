"""'drafttwin twin run | query' and 'plant serve' from the command line: several machines in
one process, the history exported, and every bad input refused in one line with exit code 2."""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pytest
from typer.testing import CliRunner

from drafttwin.cli import app

pytestmark = pytest.mark.timeout(120)


def _run(*args: str):  # noqa: ANN202
    return CliRunner().invoke(app, list(args))


def _one_line_error(res, *needles: str) -> None:  # noqa: ANN001
    assert res.exit_code == 2, res.stdout + res.stderr
    assert "Traceback" not in res.stderr
    assert res.stderr.startswith("error:")
    for n in needles:
        assert n in res.stderr, res.stderr


def test_two_machines_in_one_process_then_query(
    twin_files: tuple[Path, Path], tmp_path: Path
) -> None:
    record, model = twin_files
    mapping = tmp_path / "hall.toml"
    mapping.write_text('[[machine]]\nname = "df-02"\nrate_hz = 100\n', encoding="utf-8")
    store = tmp_path / "store"
    res = _run("twin", "run", "--model", str(model), "--mapping", str(mapping), "--store", str(store),
               "--source", f"replay:{record}?speed=max&machine=df-01",
               "--source", f"replay:{record}?speed=max&machine=df-02", "--json")  # fmt: skip
    assert res.exit_code == 0, res.stderr
    status = json.loads(res.stdout)
    assert {m: s["processed"] for m, s in status["machines"].items()} == {
        "df-01": 600,
        "df-02": 600,
    }
    out = tmp_path / "df02.csv"
    res = _run("twin", "query", "--store", str(store), "--machine", "df-02", "--from", "1",
               "--to", "2", "--out", str(out), "--json")  # fmt: skip
    assert res.exit_code == 0, res.stderr
    info = json.loads(res.stdout)
    assert info["rows"] == 101
    assert [m["samples"] for m in info["machines"]] == [600, 600]
    frame = pd.read_csv(out)
    plant = pd.read_parquet(record)
    assert frame["time"].iloc[0] == pytest.approx(1.0)
    assert frame["front"].to_numpy() == pytest.approx(
        plant["front"].to_numpy()[99:200], nan_ok=True
    )
    assert {"front_physics", "front_twin", "back_residual", "supply_hz"} <= set(frame.columns)
    events = _run("twin", "query", "--store", str(store), "--events", "--out",
                  str(tmp_path / "ev.parquet"))  # fmt: skip
    assert events.exit_code == 0, events.stderr
    # each machine starts learning its healthy state (no detector file: 600 s, more than the
    # 6-s record)
    kinds = set(pd.read_parquet(tmp_path / "ev.parquet")["kind"])
    assert kinds == {"learning", "source-live", "source-ended"}


@pytest.mark.parametrize(
    ("source", "needles"),
    [
        ("foo:bar", ("--source", "unknown source")),
        ("replay:{tmp}/missing.parquet", ("--source", "file not found")),
        ("replay:{record}?speed=0", ("--source", "speed")),
        ("replay:{record}?sped=2", ("--source", "unknown option")),
        ("opcua:http://x", ("--source", "bad OPC UA address")),
        # a typo in the port: a traceback (MQTT) or a source retrying it all run (OPC UA)
        ("mqtt://127.0.0.1:notaport", ("--source", "bad address", "1 to 65535")),
        ("mqtt://127.0.0.1:99999", ("--source", "bad address")),
        ("mqtt://127.0.0.1:", ("--source", "bad address")),
        ("opcua:opc.tcp://127.0.0.1:notaport", ("--source", "bad address")),
    ],
)
def test_bad_sources_are_refused(
    source: str, needles: tuple[str, ...], twin_files: tuple[Path, Path], tmp_path: Path
) -> None:
    record, model = twin_files
    text = source.format(tmp=tmp_path, record=record)
    _one_line_error(_run("twin", "run", "--model", str(model), "--source", text), *needles)


def test_bad_run_options_are_refused(twin_files: tuple[Path, Path], tmp_path: Path) -> None:
    record, model = twin_files
    base = ["twin", "run", "--model", str(model), "--source", f"replay:{record}"]
    _one_line_error(_run(*base, "--source", f"replay:{record}"), "comes from two sources",
                    "replay:FILE?machine=NAME")  # fmt: skip
    # two live servers: the fix named replays (neither was one)
    _one_line_error(_run("twin", "run", "--model", str(model), "--source",
                         "opcua:opc.tcp://127.0.0.1:1", "--source", "mqtt://127.0.0.1:1"),
                    "comes from two sources", "run one twin per server")  # fmt: skip
    _one_line_error(_run(*base, "--physics", "medium"), "--physics")
    _one_line_error(_run(*base, "--http", "127.0.0.1:web"), "--http", "bad address")
    others = tmp_path / "others.toml"  # a replay names its machine: the mapping's were ignored
    others.write_text('[[machine]]\nname = "df-09"\n', encoding="utf-8")
    _one_line_error(_run(*base, "--mapping", str(others)), "names df-09, which no --source serves")
    _one_line_error(_run(*base, "--http", "0.0.0.0:8050", "--token", "short"), "--token")
    bad = tmp_path / "bad.toml"
    for text, needle in (("[[machine]\n", "not valid TOML"),
                         ('[[machine]]\nname = "a"\ncolour = 1\n', "machine.0.colour"),
                         ('[[machine]]\nname = "a"\n[[machine]]\nname = "a"\n', "named twice"),
                         ('[[machine]]\nname = "a"\nfields = ["seq", "time", "front"]\n',
                          "fields lack")):  # fmt: skip
        bad.write_text(text, encoding="utf-8")
        _one_line_error(_run(*base, "--mapping", str(bad)), str(bad), needle)
    plain = tmp_path / "plain.csv"
    pd.read_parquet(record).drop(columns=["supply_hz"]).to_csv(plain, index=False)
    _one_line_error(_run("twin", "run", "--model", str(model), "--source", f"replay:{plain}"),
                    "no set-point column 'supply_hz'")  # fmt: skip


def test_bad_query_and_serve_options_are_refused(tmp_path: Path) -> None:
    _one_line_error(_run("twin", "query", "--store", str(tmp_path)), "no twin store here")
    _one_line_error(_run("twin", "query", "--store", str(tmp_path), "--from", "2", "--to", "1"),
                    "--to")  # fmt: skip
    _one_line_error(_run("twin", "query", "--store", str(tmp_path), "--out", str(tmp_path / "a.xls")),
                    "unsupported output file type")  # fmt: skip
    _one_line_error(_run("plant", "serve"), "give one of --opcua and --mqtt")
    _one_line_error(_run("twin", "relearn", "--http", "127.0.0.1:1", "--machine", "a/b?c"),
                    "--machine", "is not a machine name")  # fmt: skip
    _one_line_error(_run("twin", "run", "--model", str(tmp_path), "--source", "replay:x.csv"),
                    "is a folder, a model file is expected")  # fmt: skip
    # a wildcard had ended in 'no MQTT broker answers there'; '/' and '' had been served
    for name in ("x#", "a+b", "a/b", ""):
        _one_line_error(_run("plant", "serve", "--mqtt", "127.0.0.1:1883", "--name", name),
                        "--name", "is not a machine name")  # fmt: skip
    _one_line_error(
        _run("plant", "serve", "--opcua", "http://x:1"), "--opcua", "bad OPC UA address"
    )
    _one_line_error(_run("plant", "serve", "--mqtt", "127.0.0.1"), "--mqtt", "bad MQTT address")
    # another scheme was taken as a host ("no MQTT broker answers at opc.tcp://..."), and a
    # bare address was told to use port 4840
    _one_line_error(_run("plant", "serve", "--mqtt", "opc.tcp://127.0.0.1:48940"), "--mqtt",
                    "is not an MQTT address", "127.0.0.1:48940")  # fmt: skip
    _one_line_error(_run("plant", "serve", "--opcua", "127.0.0.1:48940"), "--opcua",
                    "opc.tcp://127.0.0.1:48940")  # fmt: skip
    _one_line_error(_run("plant", "serve", "--opcua", "opc.tcp://127.0.0.1:4840", "--physics", "x"),
                    "--physics")  # fmt: skip


def test_retention_keeps_the_newest_hours(twin_files: tuple[Path, Path], tmp_path: Path) -> None:
    record, model = twin_files
    store = tmp_path / "store"
    res = _run("twin", "run", "--model", str(model), "--source", f"replay:{record}?speed=max",
               "--store", str(store), "--retention-hours", str(2.0 / 3600), "--quiet")  # fmt: skip
    assert res.exit_code == 0, res.stderr
    res = _run("twin", "query", "--store", str(store), "--json")
    (m,) = json.loads(res.stdout)["machines"]
    assert m["samples"] == 201  # the last 2 s at 100 Hz, both ends included
    assert m["last_s"] == pytest.approx(6.0)


def test_the_summary_gives_no_transport_figure_for_a_source_off_the_wall_clock(capsys):
    """A replay of old records stamps its samples years back: its 'transport' is the age of the
    records, not a latency (it printed 95,867,089,617 ms); a live source's figure stays."""
    from drafttwin.cli.twin_cmds import _print_status

    def machine(p50_ms: float) -> dict:
        return {"state": "live", "received": 1, "processed": 1, "dropped": 0, "late": 0,
                "duplicate": 0, "skipped": 0, "spikes_rejected": 0,
                "transport_ms": {"p50": p50_ms, "p99": p50_ms + 5.0}}  # fmt: skip

    _print_status({"rows": 2, "wall_s": 1.0, "store": None,
                   "latency_ms": {"p50": 1.0, "p99": 2.0, "max": 3.0},
                   "machines": {"replayed": machine(9.5867e10), "live": machine(12.0)}})  # fmt: skip
    out = capsys.readouterr().out
    assert "replayed: the source's times are +26629.7 h off the wall clock" in out, out
    assert "replayed: source -> received" not in out
    assert "live: source -> received (transport and the source's own lateness): p50 12.0 ms" in out


def test_the_live_benchmarks_speed_default_is_the_studys():
    """The CLI states the default apart (it imports the study lazily): the two must agree."""
    import inspect

    from drafttwin.cli.faults_cmds import benchmark_faults
    from drafttwin.studies.faults.live import SPEED

    assert inspect.signature(benchmark_faults).parameters["speed"].default == SPEED


def test_max_samples_stops_at_the_count(twin_files: tuple[Path, Path], tmp_path: Path) -> None:
    # a replay at full speed hands hundreds of samples in one turn of the loop: 300 were
    # processed for --max-samples 1
    record, model = twin_files
    for n in (1, 37):
        res = _run("twin", "run", "--model", str(model), "--source", f"replay:{record}?speed=max",
                   "--store", str(tmp_path / f"s{n}"), "--max-samples", str(n), "--json")  # fmt: skip
        assert res.exit_code == 0, res.stderr
        assert json.loads(res.stdout)["rows"] == n


def test_fit_detector_replaces_no_file_that_is_not_a_detector(
    twin_files: tuple[Path, Path], tmp_path: Path
) -> None:
    """--out naming a model (or a record) by mistake had turned it into the detector's JSON."""
    record, model = twin_files
    for victim in (tmp_path / "other.dtm", tmp_path / "victim.parquet"):
        victim.write_bytes((model if victim.suffix == ".dtm" else record).read_bytes())
        before = victim.read_bytes()
        res = CliRunner().invoke(app, ["twin", "fit-detector", "--model", str(model), "--healthy",
                                       str(record), "--out", str(victim)])  # fmt: skip
        assert res.exit_code == 2, res.output
        assert "exists and is not a detector file" in res.output
        assert victim.read_bytes() == before


@pytest.mark.parametrize(("address", "said"), [
    ("http://127.0.0.1:{port}/", "no twin answers at http://127.0.0.1:{port}/ ("),
    ("127.0.0.1:99999", "bad address '127.0.0.1:99999'"),
])  # fmt: skip
def test_relearn_takes_the_address_the_twin_prints(address: str, said: str) -> None:
    """'http://127.0.0.1:8050/' (what 'twin run' prints) had been looked up as a host name
    ('Name or service not known'); a port beyond 65535 read as a refused connection."""
    from ._twin import free_port

    port = free_port()
    res = CliRunner().invoke(app, ["twin", "relearn", "--http", address.format(port=port),
                                   "--machine", "fa320a"])  # fmt: skip
    assert res.exit_code == 2 and said.format(port=port) in res.output, res.output
    assert "Name or service not known" not in res.output


def test_relearn_of_an_unknown_machine_names_where_a_hall_lists_its_machines() -> None:
    """The fix pointed at GET /api/machines, which a hall does not serve (its list is
    /api/hall)."""
    import threading
    from http.server import BaseHTTPRequestHandler, HTTPServer

    class NoMachine(BaseHTTPRequestHandler):
        def do_POST(self) -> None:  # noqa: N802  (the http.server name)
            self.send_response(404)
            self.end_headers()
            self.wfile.write(b'{"detail": "no machine nosuch"}')

        def log_message(self, *args: object) -> None:
            pass

    server = HTTPServer(("127.0.0.1", 0), NoMachine)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        res = CliRunner().invoke(app, ["twin", "relearn", "--http",
                                       f"127.0.0.1:{server.server_port}", "--machine", "nosuch"])  # fmt: skip
    finally:
        server.shutdown()
    assert res.exit_code == 2 and "HTTP 404" in res.output
    assert "GET /api/machines" in res.output and "GET /api/hall" in res.output


def test_fit_detector_reads_a_record_of_other_column_names_with_columns(
    twin_files: tuple[Path, Path], tmp_path: Path
) -> None:
    """Its own error asked for --columns, which it did not have."""
    from drafttwin.plant import Plant

    _, model = twin_files
    record = tmp_path / "healthy.csv"
    Plant().run(40.0, 100.0, seed=4).series.to_frame().rename(
        columns={"front": "frnt"}).to_csv(record, index=False)  # fmt: skip
    args = ["twin", "fit-detector", "--model", str(model), "--healthy", str(record), "--out",
            str(tmp_path / "d.json")]  # fmt: skip
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 2 and "--columns frnt=front" in res.output, res.output
    res = CliRunner().invoke(app, [*args, "--columns", "frnt=front"])
    assert res.exit_code == 0, res.output
    assert (tmp_path / "d.json").is_file()


def test_fit_detector_refuses_a_healthy_record_given_twice(
    twin_files: tuple[Path, Path], tmp_path: Path
) -> None:
    """A record given twice (its name twice, or a copy) counted its running twice towards
    the thresholds' length, as diagnose's --healthy had (that refuses it since)."""
    record, model = twin_files
    copy = tmp_path / f"copy{record.suffix}"
    copy.write_bytes(record.read_bytes())
    for second in (record, copy):
        res = CliRunner().invoke(app, ["twin", "fit-detector", "--model", str(model), "--healthy",
                                       f"{record},{second}", "--out", str(tmp_path / "d.json")])  # fmt: skip
        assert res.exit_code == 2, res.output
        line = " ".join(res.output.split())
        assert f"{second}: --healthy: holds the same samples as {record}" in line
        assert "give each healthy record once" in line
        assert not (tmp_path / "d.json").exists()
