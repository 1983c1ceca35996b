"""'drafttwin twin hall': a hall of machines spread over Ray actors (a private local Ray with 2
CPUs), one store per shard, read back as one by 'twin query'; a shard killed with SIGKILL is
started again by Ray and recovers what it missed from the server's history, counted against
the plant's log by 'twin audit'; and the hall's refusals."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import time
from pathlib import Path

import pytest
from typer.testing import CliRunner

from drafttwin.cli import app
from drafttwin.twin.store.history import read_events

from ._twin import cli, env, free_port, run_cli

pytest.importorskip("ray", reason="the hall runs on Ray (pip install 'drafttwin[ray]')")

pytestmark = pytest.mark.timeout(240)

HALL = "".join(f'[[machine]]\nname = "fa320a-{k}"\n\n' for k in (1, 2, 3))


def _kill_a_shard(hall: subprocess.Popen[str], store: Path, timeout: float = 120) -> Path:
    """SIGKILL shard 0's process (the one holding its store) once both shards committed rows;
    that shard's folder."""
    deadline = time.monotonic() + timeout
    wals = [store / f"shard-{i}-of-2" / "twin.duckdb.wal" for i in (0, 1)]
    while not all(w.exists() for w in wals):  # the stores are made
        assert hall.poll() is None and time.monotonic() < deadline, "the shards never started"
        time.sleep(0.2)
    time.sleep(3.0)  # connected and committing rows (every 100 ms)
    target = wals[0].parent.resolve()  # shard 0; both run for --duration from their start
    for fds in Path("/proc").glob("[0-9]*/fd"):  # the process that holds its store open
        with contextlib.suppress(OSError):
            if any(Path(os.readlink(fd)).parent == target for fd in fds.iterdir()):
                os.kill(int(fds.parent.name), signal.SIGKILL)
                return target
    raise AssertionError(f"no process holds {target}")


@pytest.mark.long  # a plant, a private Ray, two twin actors and a restart: 32-50 s
@pytest.mark.skipif(not Path("/proc/self/fd").is_dir(), reason="finds the shard through /proc")
def test_a_hall_on_two_ray_actors_survives_a_killed_shard(
    twin_files: tuple[Path, Path], tmp_path: Path
) -> None:
    _, model = twin_files
    mapping = tmp_path / "hall.toml"
    mapping.write_text(HALL, encoding="utf-8")
    url = f"opc.tcp://127.0.0.1:{free_port()}"
    log, store = tmp_path / "plant.parquet", tmp_path / "store"
    plant = subprocess.Popen(cli("plant", "serve", "--opcua", url, "--machines", "3", "--physics",
                                 "reduced", "--log", str(log), "--history", "60"), env=env(),
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    procs = [plant]
    try:
        assert plant.stderr is not None and "serving" in plant.stderr.readline()
        hall = subprocess.Popen(cli("twin", "hall", "--model", str(model), "--source", f"opcua:{url}",
                                    "--mapping", str(mapping), "--store", str(store), "--shards",
                                    "2", "--duration", "12", "--commit-ms", "100", "--json"),
                                env=env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                text=True)  # fmt: skip
        procs.append(hall)
        killed = _kill_a_shard(hall, store)  # Ray starts it again and retries its run
        out, err = hall.communicate(timeout=180)
        assert hall.returncode == 0, err
    finally:
        for p in procs:  # the plant by SIGTERM: it writes its log
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(timeout=30)
    shards = json.loads(out)["shards"]
    # shard I has the mapping's machines I, I+2: each machine in exactly one actor
    assert [sorted(s["machines"]) for s in shards] == [["fa320a-1", "fa320a-3"], ["fa320a-2"]]
    assert [Path(s["store_dir"]).name for s in shards] == ["shard-0-of-2", "shard-1-of-2"]
    for s in shards:
        for m in s["machines"].values():
            assert m["processed"] > 200 and m["dropped"] == 0  # 12 s at 100 Hz, start-up aside
    query = run_cli("twin", "query", "--store", str(store), "--json")
    assert query.returncode == 0, query.stderr
    info = json.loads(query.stdout)
    assert [m["machine"] for m in info["machines"]] == ["fa320a-1", "fa320a-2", "fa320a-3"]
    # the restarted shard read what it missed from the server's history ...
    events = read_events(killed)
    recovered = events[events["kind"] == "history"]["detail"]
    assert len(recovered) >= 1 and all("samples recovered" in d for d in recovered), events
    # ... so, counted against the plant's log, every machine's samples from its first to its
    # last stored one are there, once, as published
    audit = run_cli("twin", "audit", "--store", str(store), "--plant-log", str(log), "--json")
    assert audit.returncode == 0, audit.stderr
    for m in json.loads(audit.stdout)["machines"]:
        assert m["stored"] > 200
        assert (m["missing_inside"], m["duplicates"], m["mismatched"], m["filled"]) == (0, 0, 0, 0)


def _error(res, *needles: str) -> None:  # noqa: ANN001
    assert res.exit_code == 2, res.stdout + res.stderr
    assert res.stderr.startswith("error:") and "Traceback" not in res.stderr
    for n in needles:
        assert n in res.stderr, res.stderr


def test_the_hall_refuses_what_would_go_wrong_in_an_actor(
    twin_files: tuple[Path, Path], tmp_path: Path
) -> None:
    record, model = twin_files
    mapping = tmp_path / "hall.toml"
    mapping.write_text(HALL, encoding="utf-8")
    store = tmp_path / "store"
    (store / "shard-0-of-2").mkdir(parents=True)
    base = ["twin", "hall", "--model", str(model), "--mapping", str(mapping), "--store", str(store)]
    run = CliRunner().invoke
    opcua = "opcua:opc.tcp://127.0.0.1:4840"
    _error(run(app, [*base, "--source", opcua, "--shards", "3"]), "hall of 2 shards", "--shards 2")
    _error(run(app, [*base, "--source", f"replay:{record}", "--shards", "2"]), "live server")
    _error(run(app, [*base, "--source", f"{opcua}?shard=0/2", "--shards", "2"]), "drop shard=")
    _error(run(app, [*base, "--source", opcua, "--shards", "4"]), "hall of 2 shards")
    _error(run(app, [*base, "--source", opcua, "--shards", "0"]), "--shards")
    fresh = [*base[:-1], str(tmp_path / "fresh")]
    # 3 machines: the option to change is --shards (it named --source)
    _error(run(app, [*fresh, "--source", opcua, "--shards", "4"]), "--shards:",
           "4 shards for 3 machine(s)", "at most 3 shards")  # fmt: skip
    # the source quoted as written, not with the shard the hall adds; shard not offered
    res = run(app, [*fresh, "--source", f"{opcua}?bogus=1", "--shards", "2"])
    _error(res, f"in '{opcua}?bogus=1'")
    assert "&shard=" not in res.stderr and "shard," not in res.stderr, res.stderr
    nobody = f"127.0.0.1:{free_port()}"
    _error(run(app, [*fresh, "--source", opcua, "--ray", nobody]), "--ray", "no Ray cluster")
    # a DuckDB file of something else is not "the store of a single 'twin run'"
    import duckdb

    other = tmp_path / "other"
    other.mkdir()
    con = duckdb.connect(str(other / "twin.duckdb"))
    con.execute("CREATE TABLE foo (a INTEGER)")
    con.close()
    _error(run(app, [*base[:-1], str(other), "--source", opcua, "--shards", "2"]),
           "holds twin.duckdb, which is not a drafttwin twin store")  # fmt: skip


@pytest.mark.long  # a plant and a private Ray: about 30-60 s
@pytest.mark.skipif(not Path("/proc/self/fd").is_dir(), reason="finds the shard through /proc")
def test_the_hall_knows_its_shards_and_sigterm_ends_it_within_5_s(
    twin_files: tuple[Path, Path], tmp_path: Path
) -> None:
    """The hall's page says each shard's real state (starting, loading, then running with its
    machines, as its store fills); SIGTERM ends it within 5 s with a message per shard. Ray's
    init puts in its own SIGTERM handler (a stack dump, no summary) and a signal raised inside
    its calls left the driver waiting: the hall keeps its own handler and lets the signal
    through between Ray's calls."""
    import urllib.request

    _, model = twin_files
    mapping = tmp_path / "hall.toml"
    mapping.write_text(HALL, encoding="utf-8")
    url, http = f"opc.tcp://127.0.0.1:{free_port()}", free_port()
    plant = subprocess.Popen(cli("plant", "serve", "--opcua", url, "--machines", "3", "--physics",
                                 "reduced"), env=env(), stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True)  # fmt: skip
    hall = None
    states: list[list[str]] = []
    try:
        assert plant.stderr is not None and "serving" in plant.stderr.readline()
        hall = subprocess.Popen(cli("twin", "hall", "--model", str(model), "--source", f"opcua:{url}",
                                    "--mapping", str(mapping), "--store", str(tmp_path / "store"),
                                    "--shards", "2", "--http", f"127.0.0.1:{http}"), env=env(),
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
        deadline = time.monotonic() + 240  # a loaded 2-core box: Ray's start, the imports
        running: list[dict] = []
        while time.monotonic() < deadline and hall.poll() is None:
            time.sleep(1.0)
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{http}/api/hall", timeout=5) as r:
                    shards = json.loads(r.read())["shards"]
            except OSError:
                continue
            states.append([s["state"] for s in shards])
            if all(s["state"] == "running" and (s["rows"] or 0) > 100 for s in shards):
                running = shards
                break
        assert running, f"the hall's page never said both shards run: {states}"
        # an operator's command through the page reaches the machine's shard (it was a 404)
        req = urllib.request.Request(f"http://127.0.0.1:{http}/api/machines/fa320a-3/relearn",
                                     method="POST")  # fmt: skip
        with urllib.request.urlopen(req, timeout=30) as r:  # noqa: S310  a local test server
            relearnt = json.loads(r.read())
        start = time.monotonic()
        hall.send_signal(signal.SIGTERM)
        out, err = hall.communicate(timeout=60)
        took = time.monotonic() - start
    finally:
        for p in (hall, plant):
            if p is not None and p.poll() is None:
                p.kill()
                p.communicate(timeout=30)
    assert {m for s in running for m in s["machines"]} == {"fa320a-1", "fa320a-2", "fa320a-3"}
    assert all(m["state"] == "live" for s in running for m in s["machines"].values())
    # "not answering": a shard too busy (importing) to answer within a second
    assert set(sum(states, [])) <= {"starting", "loading", "running", "not answering"}, states
    assert states[-1] == ["running", "running"]
    assert took < 5.0, f"{took:.1f} s: {err}"
    assert hall.returncode == 0, err
    assert "stopped by SIGTERM: shards 0, 1 committed what they received" in err, err
    assert "Traceback" not in err and "SIGTERM received" not in err, err
    assert "still starting" not in err, err
    assert relearnt["machine"] == "fa320a-3" and relearnt["detector"]["state"] == "learning"
    # its summary after the stop (a hall ends by a signal as a rule: it had printed none)
    assert "hall: 2 twins" in out and "fa320a-1" in out and "fa320a-3" in out, out


class _Ref:
    def __init__(self, value: object, done: bool = True) -> None:
        self.value, self.done = value, done


class _FakeRay:
    """Just what the hall's driver asks of Ray: wait, get, and an error type."""

    class exceptions:  # noqa: N801  Ray's module layout
        class RayError(Exception):
            pass

    @staticmethod
    def wait(refs: list[_Ref], num_returns: int = 1, timeout: float = 0) -> tuple[list, list]:
        return [r for r in refs if r.done], [r for r in refs if not r.done]

    @staticmethod
    def get(ref: _Ref, timeout: float = 0) -> object:
        if isinstance(ref.value, Exception):
            raise ref.value
        return ref.value


class _Actor:
    def __init__(self, answer: _Ref) -> None:
        self.status = type("M", (), {"remote": staticmethod(lambda: answer)})


def test_each_shard_says_its_real_state() -> None:
    """The driver's poll: a shard not yet up is starting, one building its twin loading, a
    running one its machines; one that answered before but not now keeps its last status as
    not answering; a finished run is ended, a failed one failed with its error."""
    from drafttwin.twin.hall import _statuses

    running = {"state": "running", "rows": 10, "machines": {"m": {"state": "live"}}}
    actors = [_Actor(_Ref(None, done=False)), _Actor(_Ref({"state": "loading"})),
              _Actor(_Ref(running)), _Actor(_Ref(None, done=False)), _Actor(_Ref(None)),
              _Actor(_Ref(None))]  # fmt: skip
    refs = [_Ref(None, done=False)] * 4 + [_Ref({"rows": 5, "machines": {}}),
                                           _Ref(RuntimeError("boom\nshard broke"))]  # fmt: skip
    before = [None, None, None, running, None, None]
    out = _statuses(_FakeRay(), actors, refs, before)
    assert [o["state"] for o in out] == ["starting", "loading", "running", "not answering",
                                         "ended", "failed"]  # fmt: skip
    assert out[3]["machines"] == running["machines"] and out[5]["error"] == "shard broke"
    # a shard started again after its process died answers "loading" at once: its machines
    # and alarms had vanished from the page, and a command to one of them answered 404
    again = _statuses(_FakeRay(), [_Actor(_Ref({"state": "loading"}))], [_Ref(None, False)],
                      [running])  # fmt: skip
    assert again[0]["state"] == "restarting" and again[0]["machines"] == running["machines"]


def test_the_hall_page_passes_an_operators_command_to_the_machines_shard() -> None:
    """A hall's machines could not be relearnt nor their alarms acknowledged (404): the page
    now routes each command to the shard watching the machine."""
    import urllib.error
    import urllib.request

    from drafttwin.twin.web.hall import HallServer, HallView

    view = HallView(2)
    view.update([{"state": "running", "machines": {"m-1": {}}},
                 {"state": "running", "machines": {"m-2": {}}}])  # fmt: skip
    calls: list[tuple] = []

    def command(shard: int, kind: str, machine: str, args: dict) -> dict:
        calls.append((shard, kind, machine, args))
        if kind == "confirm":
            return {"status": 409, "body": "nothing to confirm"}
        return {"status": 200, "body": {"machine": machine, "kind": kind}}

    def post(path: str) -> tuple[int, str]:
        req = urllib.request.Request(f"http://127.0.0.1:{port}{path}", method="POST")
        try:
            with urllib.request.urlopen(req, timeout=10) as r:  # noqa: S310  a local test server
                return r.status, r.read().decode()
        except urllib.error.HTTPError as exc:
            return exc.code, exc.read().decode()

    port = free_port()
    with HallServer(view, ("127.0.0.1", port), None):
        before = post("/api/machines/m-2/relearn")  # no shard bound yet
        view.bind_commands(command)
        relearnt = post("/api/machines/m-2/relearn")
        acked = post("/api/machines/m-1/alarms/acknowledge?alarm=A1&comment=checked")
        refused = post("/api/machines/m-1/alarms/confirm")
        unknown = post("/api/machines/m-9/relearn")
    assert before[0] == 404
    assert relearnt == (200, '{"machine":"m-2","kind":"relearn"}')
    assert acked[0] == 200 and refused[0] == 409 and "nothing to confirm" in refused[1]
    assert unknown[0] == 404 and "no machine 'm-9' in the hall" in unknown[1]
    assert calls == [(1, "relearn", "m-2", {}),
                     (0, "acknowledge", "m-1", {"comment": "checked", "alarm": "A1"}),
                     (0, "confirm", "m-1", {"comment": "", "alarm": None})]  # fmt: skip


def test_a_shards_command_answers_as_the_twins_api(twin_files: tuple[Path, Path]) -> None:
    from drafttwin.twin.build import build_service
    from drafttwin.twin.hall import shard_command

    record, model = twin_files
    service = build_service(model, [f"replay:{record}?machine=df-01"])
    relearnt = shard_command(service, "relearn", "df-01", {})
    assert relearnt["status"] == 200 and relearnt["body"]["detector"]["state"] == "learning"
    taken = shard_command(service, "acknowledge", "df-01", {})
    assert taken == {"status": 200, "body": {"machine": "df-01", "taken": 0, "alarms": []}}
    assert shard_command(service, "acknowledge", "df-01", {"alarm": "x"})["status"] == 404
    assert shard_command(service, "relearn", "nobody", {})["status"] == 404
