"""``plant replay`` stopped before every file is out writes no manifest and does not say it
did (it had printed "wrote MANIFEST" for an earlier run's file)."""

from __future__ import annotations

import signal
import subprocess
import time
from pathlib import Path

import pytest

from ._twin import cli, env, free_port, plant_record

pytestmark = pytest.mark.timeout(120)


@pytest.mark.parametrize("earlier", [False, True])
def test_a_stopped_replay_writes_no_manifest_and_says_so(tmp_path: Path, earlier: bool) -> None:
    record = plant_record(tmp_path, duration_s=30.0)
    manifest = tmp_path / "manifest.json"
    if earlier:
        manifest.write_text('{"an": "earlier run"}\n')
    proc = subprocess.Popen(cli("plant", "replay", "--mqtt", f"127.0.0.1:{free_port()}",
                                "--records", str(record), "--speed", "1", "--manifest",
                                str(manifest)),
                            env=env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)  # fmt: skip
    assert proc.stderr is not None
    first = proc.stderr.readline()  # "replaying ...": the files are read, serving begins
    time.sleep(2.0)  # serving, far from the record's end (a fixed 6 s after the start could
    # still be importing on a busy machine)
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=30)
    err = first + err
    assert first.startswith("replaying"), err
    assert "stopped by SIGTERM" in err and "Traceback" not in err, err
    assert f"wrote {manifest}" not in out, out
    assert "not written: the replay stopped before every file was played" in " ".join(err.split())
    if earlier:
        assert manifest.read_text() == '{"an": "earlier run"}\n'
        assert "earlier run's" in err
    else:
        assert not manifest.exists()


def test_a_record_of_other_column_names_is_replayed_with_columns(tmp_path: Path) -> None:
    """The reader's error asked for --columns, which replay did not have."""
    import pandas as pd

    from ._twin import run_cli

    record = plant_record(tmp_path, duration_s=4.0)
    renamed = tmp_path / "renamed.csv"
    pd.read_parquet(record).rename(columns={"front": "frnt"}).to_csv(renamed, index=False)
    args = ["plant", "replay", "--mqtt", f"127.0.0.1:{free_port()}", "--records", str(renamed),
            "--speed", "100"]  # fmt: skip
    refused = run_cli(*args)
    assert refused.returncode == 2 and "--columns frnt=front" in refused.stderr, refused.stderr
    played = run_cli(*args, "--columns", "frnt=front")
    assert played.returncode == 0, played.stderr
    assert "published replay: 400 samples" in played.stdout, played.stdout
