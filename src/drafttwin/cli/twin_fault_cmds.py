"""``drafttwin twin fit-detector``: the live twin's fault detector, fitted on healthy records
and stored next to the model (docs/twin.md, 'Faults live')."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer

from drafttwin.cli._groups import stops_cleanly
from drafttwin.cli._options import (
    ColumnsOpt,
    FarPerDayOpt,
    JsonOpt,
    file_out,
    files_in,
    machine_name,
    number,
    path_in,
)
from drafttwin.cli.twin_cmds import twin_app
from drafttwin.cli.typer_app import console, print_json
from drafttwin.errors import ConfigError

ModelOpt = Annotated[Path, path_in("--model", "The model file (.dtm) the twin runs.")]
HealthyOpt = Annotated[str, files_in(
    "--healthy", "Healthy records of the machine(s), comma-separated: .csv/.parquet with a motor "
    "column (e.g. 'drafttwin generate'), or logs of 'plant serve --log' (each machine in it a "
    "record): they set the thresholds.")]  # fmt: skip
ReferenceOpt = Annotated[float, number("--reference", "Seconds at the start of a run (and after "
                         "each alarm) that set the baseline; no decisions there.")]  # fmt: skip
PostOpt = Annotated[float, number("--post", "Seconds after an alarm whose mean shift is ranked for the probable cause.")]  # fmt: skip
DetectorOutOpt = Annotated[Path | None, file_out("--out", "Where to write it (default: "
                           "MODEL.dtm.detector.json, which 'twin run' finds).")]  # fmt: skip


@twin_app.command("fit-detector")
@stops_cleanly("nothing was written")
def twin_fit_detector(
    model: ModelOpt,
    healthy: HealthyOpt,
    far_per_day: FarPerDayOpt = 1.0,
    reference: ReferenceOpt = 15.0,
    post: PostOpt = 20.0,
    out: DetectorOutOpt = None,
    columns: ColumnsOpt = None,
    as_json: JsonOpt = False,
) -> None:
    """Fit the live fault detector on healthy records and store it with the model.

    The residuals of each record against the model's physics (open loop, the rollers and the
    motor, in 1-s blocks) set each CUSUM's scale, its AR(1) coefficient and a threshold for the
    false-alarm rate asked, as 'drafttwin diagnose' does offline. 'twin run' takes it as the
    prior each machine learns its own healthy state on (2 min instead of 10 when it watches
    the angle lags: give at least 7 min of healthy running in all), or with --learn 0 as the
    detector of every machine. The file names the machines its records were made on (from
    their sidecars) and is tied to the model by its SHA-256: refitting the model needs a new
    detector.
    """
    from drafttwin.cli._data import Channels, pairs
    from drafttwin.cli._healthy import refuse_repeated
    from drafttwin.diagnosis.detect import FaultDetector
    from drafttwin.diagnosis.residuals import record_features
    from drafttwin.twin.build import load_twin_model
    from drafttwin.twin.faultwatch import detector_path, plant_log_series, save_detector
    from drafttwin.twin.live import physics_train
    from drafttwin.wire.identity import recorded_identity

    # a record of other column names (its own error asks for --columns)
    reading = Channels(columns=pairs(columns, "--columns", "v1=front,v2=second") or None)
    files = [p.strip() for p in healthy.split(",") if p.strip()]
    if not files:
        raise ConfigError("no healthy record", where="--healthy", fix="give one or more files")
    target = out if out is not None else detector_path(model)
    _replaceable_detector_file(target)  # before the work
    fitted = load_twin_model(model)
    train = physics_train(fitted, "reduced")  # the physics the live twin steps
    labelled: list[tuple[str, Any]] = []
    for p in files:  # a plant log holds one record per machine; anything else is one record
        logged = plant_log_series(Path(p))
        labelled += ([(p, reading.read(p))] if logged is None else
                     [(p if len(logged) == 1 else f"{p} (record {k + 1})", s)
                      for k, s in enumerate(logged)])  # fmt: skip
    refuse_repeated(labelled)
    series = [s for _, s in labelled]
    features = [record_features(train, s) for s in series]
    detector = FaultDetector(far_per_day=far_per_day, reference_s=reference).fit(features)
    machines = sorted({i.serial for p in files if (i := recorded_identity(Path(p))) is not None})
    save_detector(target, detector, model, files, post, machines)
    result = {"detector": str(target), "model": str(model), "fitted_on": files,
              "machines": machines, "post_s": post, **detector.describe()}  # fmt: skip
    if as_json:
        print_json(result)
        return
    made_on = f" of {', '.join(machines)}" if machines else ""
    console.print(f"fitted on {len(series)} record(s){made_on}: CUSUM threshold h = {detector.h_:.2f} "
                  f"(k = {detector.k:g}, {far_per_day:g} false alarm(s) per 24 h), "
                  f"blocks of {detector.block_s_:g} s, baseline {reference:g} s")  # fmt: skip
    for note in (detector.levels_note(), detector.lags_note()):
        if note is not None:
            console.print(note)
    uses = (f"'twin run --model {model}' uses it" if out is None or target == detector_path(model)
            else f"give it with 'twin run --model {model} --detector {target}'")  # fmt: skip
    console.print(f"wrote {target} ({uses})")


def _replaceable_detector_file(target: Path) -> None:
    """Refuse an ``--out`` that exists and is not a detector file (a model given by mistake
    had become 6.9 kB of JSON: 'fit --out' refuses the same)."""
    import json

    from drafttwin.twin.faultwatch import FORMAT

    if not target.is_file() or target.stat().st_size == 0:
        return
    try:
        doc = json.loads(target.read_bytes()[:10_000_000])
    except (OSError, ValueError):
        doc = None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise ConfigError("exists and is not a detector file, which --out would replace",
                          source=target, where="--out",
                          fix="name a new file (or a detector file to replace)")  # fmt: skip


TwinPageOpt = Annotated[str, typer.Option("--http", help="The running twin's page, HOST:PORT (its 'twin run --http').")]  # fmt: skip


RelearnMachineOpt = Annotated[str, machine_name("--machine", "The machine that was serviced.")]
RelearnTokenOpt = Annotated[str | None, typer.Option("--token", envvar="DRAFTTWIN_TOKEN",
                            help="The twin's token, if it has one.")]  # fmt: skip


@twin_app.command("relearn")
def twin_relearn(http: TwinPageOpt, machine: RelearnMachineOpt,
                 token: RelearnTokenOpt = None, as_json: JsonOpt = False) -> None:  # fmt: skip
    """After maintenance: the running twin forgets the machine's learned healthy state and
    learns it again (no fault alarm meanwhile, then watched with the new baseline). Asks the
    twin's REST API (POST /api/machines/NAME/relearn)."""
    import json
    import urllib.error
    import urllib.parse
    import urllib.request

    # the address as the twin prints its page (http://HOST:PORT/) is taken too
    address = http.strip().removeprefix("http://").rstrip("/")
    host, _, port = address.rpartition(":")
    if not host or not port.isdigit() or not 1 <= int(port) <= 65535 or "/" in address:
        raise ConfigError(f"bad address {http!r}", where="--http",
                          fix="write HOST:PORT (the twin's 'twin run --http'), e.g. 127.0.0.1:8050")  # fmt: skip
    url = f"http://{host}:{port}/api/machines/{urllib.parse.quote(machine, safe='')}/relearn"
    req = urllib.request.Request(url, method="POST", headers=(
        {"Authorization": f"Bearer {token}"} if token else {}))  # fmt: skip
    not_a_twin = ConfigError(f"the server at {host}:{port} is not a twin (its answer is not "
                             "the twin's JSON)", where="--http",
                             fix="give the address of a running 'twin run --http' or 'twin "
                             "hall --http'")  # fmt: skip
    try:
        with urllib.request.urlopen(req, timeout=10) as r:  # noqa: S310  the address the user gave
            doc = json.loads(r.read())
    except urllib.error.HTTPError as exc:
        try:  # the twin answers {"detail": ...}; anything else (a web page) is another server
            detail = str(json.loads(exc.read())["detail"])[:200]
        except (ValueError, KeyError, TypeError):
            raise not_a_twin from None
        where, fix = {401: ("--token", "give the twin's --token (or DRAFTTWIN_TOKEN)"),
                      404: ("--machine", "give a machine the twin watches (GET /api/machines "
                                         "lists them; a hall's: GET /api/hall)"),
                      409: ("--machine", "the twin runs without a fault detector (--detector "
                                         "none)")}.get(exc.code, ("--http", "see the twin's log"))  # fmt: skip
        raise ConfigError(f"the twin refused: HTTP {exc.code} {detail}", where=where,
                          fix=fix) from None  # fmt: skip
    except ValueError:  # a 200 that is not JSON
        raise not_a_twin from None
    except (urllib.error.URLError, OSError) as exc:
        raise ConfigError(f"no twin answers at {http} ({getattr(exc, 'reason', exc)})",
                          where="--http", fix="give the address of a running 'twin run --http'") from None  # fmt: skip
    if not isinstance(doc, dict) or not isinstance(doc.get("detector"), dict):
        raise not_a_twin
    if as_json:
        print_json(doc)
        return
    d = doc["detector"]
    console.print(f"{machine}: learning its healthy state again, {d.get('left_s', d.get('learn_s'))} s "
                  "of running; no fault alarm meanwhile")  # fmt: skip
