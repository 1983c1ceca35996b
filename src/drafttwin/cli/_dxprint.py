"""What ``drafttwin diagnose`` prints: the verdict, the ranked causes and their look-alikes,
the sliver's evidence, and the notes on a record that sets its own thresholds."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from rich import box
from rich.table import Table

from drafttwin.cli.typer_app import console


def print_diagnosis(result: dict[str, Any], report: Path | None) -> None:
    alarm = result["alarm"]
    console.print(f"thresholds from {result['thresholds_from']}")
    for note in result.get("notes", []):
        console.print(f"[yellow]note:[/] {note}")
    if alarm is None and not result.get("judged", True):
        console.print("no alarm, and no verdict: nothing was judged")
    elif alarm is None and result.get("reference_alarms_s"):
        console.print("no alarm after the first half: the residuals stayed within the "
                      "thresholds there (for the alarms inside it, see the note)")  # fmt: skip
    elif alarm is None:
        console.print("no alarm: the residuals stayed within the thresholds")
    else:
        console.print(f"[bold red]alarm[/] at {alarm['time_s']:.1f} s ({alarm['test']}), change "
                      f"estimated at {alarm['onset_s']:.1f} s")  # fmt: skip
        watched = result["watched_from_s"]
        if watched is not None and alarm["onset_s"] <= watched + 1.0:
            console.print(f"the record is watched from {result['watched_from_s']:.1f} s (before "
                          "that it is its own baseline): the change may have begun earlier")  # fmt: skip
        table = Table(title="ranked causes (p: relative among the candidates; fit: absolute)",
                      box=box.SIMPLE_HEAD, pad_edge=False)  # fmt: skip
        for col in ("#", "cause", "severity", "95 % interval", "p rel.", "fit chi2/dof (p)"):
            # full cause names on one line; the rest wraps inside its cell, never cut
            table.add_column(col, overflow="fold", no_wrap=col == "cause")
        for i, c in enumerate(result["causes"]):
            fit = ("rule" if c["fit_p"] is None else
                   f"{c['chi2']:.3g}/{c['dof']} ({c['fit_p']:.2g})" + ("" if c["fits"] else " no fit"))  # fmt: skip
            table.add_row(str(i + 1), f"{c['element']}:{c['kind']}", f"{c['severity']:.4g}",
                          c["interval_text"], f"{c['probability']:.2f}", fit)  # fmt: skip
        console.print(table)
        for i, c in enumerate(result["causes"]):  # below the table: long lists wrap as text
            if c["group"]:
                console.print(f"{i + 1} {c['element']}:{c['kind']}: same signature as "
                              f"{', '.join(_marked(c, result['causes']))}")  # fmt: skip
        for i, c in enumerate(result["causes"]):  # each cause's severity in its own unit
            console.print(f"{i + 1} severity: {c['parameter']}")
        if result.get("verdict"):
            colour = "green" if result["explained"] else "bold red"
            console.print(f"[{colour}]{result['verdict']}[/]")
        for c in result["causes"]:
            g = c.get("growth")
            if g is not None and g["growing"]:
                console.print(f"{c['element']}:{c['kind']} is still growing: "
                              f"{g['rate_per_s']:.3g} per s [{g['rate_interval'][0]:.3g}, "
                              f"{g['rate_interval'][1]:.3g}], {g['severity_at_end']:.4g} "
                              f"[{g['interval_at_end'][0]:.4g}, {g['interval_at_end'][1]:.4g}] "
                              f"at {g['at_time_s']:.1f} s")  # fmt: skip
    if report is not None:
        console.print(f"wrote {report}")


def print_sliver(ev: dict[str, Any]) -> None:
    """The sliver channel's evidence, a few lines."""
    console.print(f"sliver ({ev['file']}): count {ev['count_ktex']:.4f} ktex, CV "
                  f"{ev['cv_pct']:.3f} %")  # fmt: skip
    for a in ev["alarms"]:
        console.print(f"  sliver alarm at {a['time_s']:.1f} s ({a['delivered_m']:.0f} m): "
                      f"chimney at {a['wavelength_m'] * 100:.2f} cm, {a['amplitude_pct']:.3f} % "
                      f"(base {a['base_pct']:.3f} %): {a['element']}"
                      + (f" (look-alikes {', '.join(a['lookalikes'])})" if a["lookalikes"] else ""))  # fmt: skip
    for e in ev.get("count_excursions", []):
        console.print(f"  at {e['time_s']:.1f} s: {e['text']}", highlight=False)
    for c in ev["chimneys"]:
        console.print(f"  whole record: {c['wavelength_m'] * 100:.2f} cm: {c['verdict']}")
    for c in ev["known_lines"]:
        console.print(f"  the machine's own line (in its healthy reference): "
                      f"{c['wavelength_m'] * 100:.2f} cm, {c['amplitude_pct']:.3f} %")  # fmt: skip
    if ev.get("count_limit") is None:
        console.print("  the count's limit not watched: the record names no nominal count")
    if not ev["chimneys"] and not ev["alarms"]:
        console.print("  no significant chimney")


def _marked(cause: dict[str, Any], causes: list[dict[str, Any]]) -> list[str]:
    """A cause's group, those its fit tells apart marked "(no fit)" (as the page says)."""
    from drafttwin.diagnosis.locate import told_apart

    apart = told_apart(cause["group"], cause["fits"],
                       {f"{c['element']}:{c['kind']}": c["fits"] for c in causes})  # fmt: skip
    return [f"{n} (no fit)" if n in apart else n for n in cause["group"]]


def assumed_half_note(dx: Any, assumed_until: float | None) -> str | None:
    """Alarms inside the first half that set the thresholds (assumed healthy): said, not
    ranked (the first alarm after it is; one inside it had hidden a belt wear at 100 s)."""
    inside = inside_alarms(dx, assumed_until)
    if not inside:
        return None
    times = ", ".join(f"{t:.1f} s" for t in inside[:5]) + (" ..." if len(inside) > 5 else "")
    return (
        f"{len(inside)} alarm(s) inside the first half that set the thresholds (at {times}): "
        "that half is not as even as assumed, or too short to set them; the first alarm "
        f"from {assumed_until:.1f} s on is ranked. Give --healthy records to trust either"
    )


def inside_alarms(dx: Any, assumed_until: float | None) -> list[float]:
    """Times (s) of the alarms inside the assumed-healthy first half."""
    return [float(a.time_s) for a in dx.detection.alarms
            if assumed_until is not None and a.time_s < assumed_until]  # fmt: skip
