"""'drafttwin twin hall': a hall of machines spread over Ray actors (a private local Ray with 2
CPUs), one store per shard, read back as one by 'twin query' and counted against the plant's
log by 'twin audit'; and the hall's refusals."""

from __future__ import annotations

import json
import signal
import subprocess
from pathlib import Path

import pytest
from typer.testing import CliRunner

from drafttwin.cli import app

from ._twin import cli, env, free_port, run_cli

pytest.importorskip("ray", reason="the hall runs on Ray (pip install 'drafttwin[ray]')")

pytestmark = pytest.mark.timeout(240)

HALL = "".join(f'[[machine]]\nname = "fa320a-{k}"\n\n' for k in (1, 2, 3))


@pytest.mark.slow  # a plant, a private Ray and two twin actors: about 40 s
def test_a_hall_of_three_machines_on_two_ray_actors(
    twin_files: tuple[Path, Path], tmp_path: Path
) -> None:
    _, model = twin_files
    mapping = tmp_path / "hall.toml"
    mapping.write_text(HALL, encoding="utf-8")
    url = f"opc.tcp://127.0.0.1:{free_port()}"
    log, store = tmp_path / "plant.parquet", tmp_path / "store"
    plant = subprocess.Popen(cli("plant", "serve", "--opcua", url, "--machines", "3", "--physics",
                                 "reduced", "--log", str(log)), env=env(),
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        assert plant.stderr is not None and "serving" in plant.stderr.readline()
        res = run_cli("twin", "hall", "--model", str(model), "--source", f"opcua:{url}",
                      "--mapping", str(mapping), "--store", str(store), "--shards", "2",
                      "--duration", "4", "--commit-ms", "100", "--json", timeout=180)  # fmt: skip
    finally:
        plant.send_signal(signal.SIGTERM)  # the plant writes its log
        try:
            plant.wait(timeout=30)
        except subprocess.TimeoutExpired:
            plant.kill()
            plant.wait(timeout=30)
    assert res.returncode == 0, res.stderr
    shards = json.loads(res.stdout)["shards"]
    # shard I has the mapping's machines I, I+2: each machine in exactly one actor
    assert [sorted(s["machines"]) for s in shards] == [["fa320a-1", "fa320a-3"], ["fa320a-2"]]
    assert [Path(s["store_dir"]).name for s in shards] == ["shard-0-of-2", "shard-1-of-2"]
    for s in shards:
        for m in s["machines"].values():
            assert m["processed"] > 200 and m["dropped"] == 0  # 4 s at 100 Hz, start-up aside
    query = run_cli("twin", "query", "--store", str(store), "--json")
    assert query.returncode == 0, query.stderr
    info = json.loads(query.stdout)
    assert [m["machine"] for m in info["machines"]] == ["fa320a-1", "fa320a-2", "fa320a-3"]
    assert info["rows"] == sum(s["store"]["committed"] for s in shards)
    audit = run_cli("twin", "audit", "--store", str(store), "--plant-log", str(log), "--json")
    assert audit.returncode == 0, audit.stderr
    for m in json.loads(audit.stdout)["machines"]:  # every sample between first and last once
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
    _error(run(app, [*fresh, "--source", opcua, "--shards", "4"]), "is empty")  # 3 machines
