"""``drafttwin twin audit``: a twin's store counted against the plant's own log (docs/twin.md)."""

from __future__ import annotations

import datetime as dt
from pathlib import Path
from typing import Annotated

import typer
from rich import box
from rich.table import Table

from drafttwin.cli._oserrors import input_path
from drafttwin.cli.app import console, print_json
from drafttwin.cli.twin_cmds import _need_twin_extra, twin_app


@twin_app.command("audit")
def twin_audit(
    store: Annotated[
        Path, typer.Option(help="Store folder a twin wrote.", callback=input_path("--store"))
    ],
    plant_log: Annotated[
        Path,
        typer.Option(
            help="The plant's log ('drafttwin plant serve --log FILE').",
            callback=input_path("--plant-log"),
        ),
    ],  # fmt: skip
    machine: Annotated[str | None, typer.Option(help="One machine (default: all).")] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print the audit as JSON.")] = False,
) -> None:
    """Count the store against the plant's log: per machine the samples published, stored,
    stored twice, stored with other values, and the runs of published samples the store lacks
    (with when the plant published them), apart from those before the twin's first and after
    its last stored sample."""
    _need_twin_extra()
    from drafttwin.twin.audit import as_json as audit_json
    from drafttwin.twin.audit import audit

    result = audit(store, plant_log, machine)
    if as_json:
        print_json({"machines": audit_json(result)})
        return
    table = Table(title=f"store {store} against {plant_log}", box=box.SIMPLE)
    cols = ("machine", "sent", "stored", "twice", "differ", "absent", "before", "after",
            "filled")  # fmt: skip
    for col in cols:
        table.add_column(col, justify="left" if col == "machine" else "right")
    for m in result:
        table.add_row(m.machine, *map(str, (m.published, m.stored, m.duplicates, m.mismatched,
                                            m.missing_inside, m.before_first, m.after_last,
                                            m.filled)))  # fmt: skip
    console.print(table)
    console.print("sent: published by the plant; twice: stored more than once; differ: stored with another time or value; "
                  "absent: published between the first and last stored sample but not stored "
                  "(runs below); before / after: published before the first / after the last "
                  "stored sample; filled: rows the twin made up for samples it never received",
                  highlight=False)  # fmt: skip
    for m in result:
        for r in m.runs:
            console.print(f"{m.machine}: {r.samples} samples missing, seq {r.first_seq}-"
                          f"{r.last_seq}, published {_clock(r.first_published_s)} to "
                          f"{_clock(r.last_published_s)}", highlight=False)  # fmt: skip


def _clock(t: float) -> str:
    return dt.datetime.fromtimestamp(t, tz=dt.UTC).strftime("%H:%M:%S.%f")[:-3] + " UTC"
