"""Model files are checked on load exactly as models are on construction.

Every field of a saved model file times every way it can be damaged (``_model_damage.py``:
wrong type, out of range, missing, unknown extra key, NaN, wrong tensor shape, truncated, not
a zip or pickle, a pickle that would run code) is refused with a ModelFileError naming the
file and the field, never a traceback, never silently used; a pickle's code never runs. A
model saved for a device this machine lacks (cuda, cuda:3, mps) loads with a warning and
predicts on the CPU, on the command line with one warning line. A path recorded in a model
file is never opened unless the user names it.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from drafttwin.cli import app
from drafttwin.data.io import write_measurements
from drafttwin.errors import ConfigError, ModelFileError
from drafttwin.models import DeviceFallbackWarning, MechanisticModel, load_model, make_model
from drafttwin.models.storage.modelfile import checksum

from .._synthetic import hyper_for, make_series, mechanistic
from ._model_damage import Case, _RunsCode, cases

CASES = cases()


@pytest.fixture(scope="module")
def series():
    return make_series(300, seed=2)[0]


@pytest.fixture(scope="module")
def good(tmp_path_factory: pytest.TempPathFactory, series) -> Path:
    path = tmp_path_factory.mktemp("model") / "gru.pt"
    make_model("gru", **hyper_for("gru")).fit(series).save(path)
    return path


def _field_names(case: Case) -> tuple[str, str] | None:
    """What the message must name for a case: the damaged field (``window`` for
    ``params.window: 0``) or the object holding it (``field params.task`` for
    ``params.task.kind: 'bogus'``, whose constructor words the problem); ``None`` for damage
    to the file as a whole."""
    head = case.name.split(":")[0]
    if head.startswith(("file", "payload")) and "." not in head:
        return None
    return head.split(".")[-1], "field " + head.rsplit(".", 1)[0]


@pytest.mark.parametrize("case", [c for c in CASES if c.expect == "refuse"], ids=lambda c: c.name)
def test_damaged_model_file_is_refused_naming_file_and_field(case, good, series, tmp_path):
    _RunsCode.marker.unlink(missing_ok=True)
    path = case.write(good, tmp_path / "damaged.pt")
    with pytest.raises(ModelFileError) as err:
        load_model(path).predict_values(series)  # load must refuse: predict never runs
    message = str(err.value)
    assert message.startswith(f"{path}: "), message
    assert "fix:" in message
    assert not _RunsCode.marker.exists(), "the pickle's code ran"
    names = _field_names(case)
    if names is not None:
        assert names[0] in message or names[1] in message, message


@pytest.mark.parametrize("device", ["cuda", "cuda:3", "mps"])
def test_model_saved_for_an_absent_device_runs_on_cpu_with_a_warning(device, good, series,
                                                                     tmp_path):  # fmt: skip
    if device.startswith("cuda") and torch.cuda.is_available() and device == "cuda":
        pytest.skip("this machine has CUDA")
    path = _with_device(good, tmp_path / "gpu.pt", device)
    with pytest.warns(DeviceFallbackWarning, match=f"saved for {device}.*running on cpu"):
        model = load_model(path)
    assert model.training.device == "cpu"
    np.testing.assert_array_equal(
        model.predict_values(series), load_model(good).predict_values(series)
    )


def _with_device(good: Path, target: Path, device: str) -> Path:
    payload = torch.load(good, weights_only=True)
    params = json.loads(payload["params_json"])
    params["training"]["__training__"]["device"] = device
    payload["params_json"] = json.dumps(params)
    payload["checksum"] = checksum(payload)  # written so on a machine with that device
    torch.save(payload, target)
    return target


def test_cli_prints_one_warning_line_for_a_cuda_model(good, series, tmp_path) -> None:
    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA")
    data = write_measurements(series, tmp_path / "data.csv")
    path = _with_device(good, tmp_path / "model.pt", "cuda")
    result = CliRunner().invoke(app, ["predict", "--model", str(path), "--data", str(data),
                                      "--out", str(tmp_path / "p.csv")])  # fmt: skip
    assert result.exit_code == 0, result.output
    lines = [ln for ln in result.output.splitlines() if ln.startswith("warning:")]
    assert lines == [
        "warning: model.pt was saved for cuda, which this machine lacks; running on cpu"
    ]
    assert (tmp_path / "p.csv").is_file()


@pytest.mark.parametrize(("edit", "words"), [
    ({"window": 0}, "field params.window: window=0 is invalid"),
    ({"horizon": 0}, "horizon=0 is invalid"),
    ({"hidden": 10**7}, "field params.hidden"),
])  # fmt: skip
def test_cli_refuses_an_invalid_model_file_with_one_message_exit_2(good, series, tmp_path,
                                                                    edit, words) -> None:  # fmt: skip
    payload = torch.load(good, weights_only=True)
    params = json.loads(payload["params_json"])
    for key, value in edit.items():
        if key == "horizon":
            params["task"]["__task__"][key] = value
        else:
            params[key] = value
    payload["params_json"] = json.dumps(params)
    path = tmp_path / "edited.pt"
    torch.save(payload, path)
    data = write_measurements(series, tmp_path / "data.csv")
    out = tmp_path / "p.csv"
    result = CliRunner().invoke(app, ["predict", "--model", str(path), "--data", str(data),
                                      "--out", str(out)])  # fmt: skip
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output
    assert words in result.output and str(path) in result.output
    assert not out.exists()


def test_a_bit_flipped_in_a_weight_is_found_by_the_checksum(good, tmp_path) -> None:
    case = next(c for c in CASES if "bit flipped" in c.name)
    with pytest.raises(ModelFileError, match="field checksum"):
        load_model(case.write(good, tmp_path / "flipped.pt"))


def test_a_file_from_before_checksums_still_loads(good, series, tmp_path) -> None:
    payload = torch.load(good, weights_only=True)
    del payload["checksum"]
    path = tmp_path / "old.pt"
    torch.save(payload, path)
    np.testing.assert_array_equal(load_model(path).predict_values(series),
                                  load_model(good).predict_values(series))  # fmt: skip


def test_every_catalogued_case_is_handled_cleanly(good, series, tmp_path) -> None:
    """The count reported in docs: all cases refused by name or run on the CPU."""
    from ._model_damage import check

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeviceFallbackWarning)
        bad = [c.name for k, c in enumerate(CASES)
               if not check(c, good, tmp_path / f"c{k}.pt", series)[0]]  # fmt: skip
    assert bad == []
    assert len(CASES) >= 100


# ----- paths stored in a model file ------------------------------------------------------
@pytest.fixture()
def fifo(tmp_path: Path) -> Path:
    """A named pipe: opening it for reading blocks until a writer comes, so any attempt to
    read it hangs the process (and the subprocess below times out)."""
    path = tmp_path / "stored.csv"
    os.mkfifo(path)
    return path


def _parallel_with_stored_paths(series, tmp_path: Path, paths: list[str]) -> Path:
    model = make_model("parallel", **hyper_for("parallel")).fit(
        series, MechanisticModel(mechanistic)
    )
    model.mechanistic_spec_ = {"kind": "file", "paths": paths}
    model.provenance_ = {"data": paths[0], "test_data": paths[0]}
    return model.save(tmp_path / "stored_paths.pt")


def test_a_stored_path_is_never_opened_by_predict(series, tmp_path, fifo) -> None:
    """predict and evaluate with the model's recorded source ask for --mechanistic instead
    of opening the recorded file (here a FIFO that would block any reader)."""
    model_file = _parallel_with_stored_paths(series, tmp_path, [str(fifo)])
    data = write_measurements(series, tmp_path / "data.csv")
    for command in (["predict", "--out", str(tmp_path / "p.csv")], ["evaluate"]):
        argv = [sys.executable, "-c", "from drafttwin.cli import app; app()", *command,
                "--model", str(model_file), "--data", str(data)]  # fmt: skip
        done = subprocess.run(argv, capture_output=True, text=True, timeout=120)
        assert done.returncode == 2, done.stderr
        assert "--mechanistic" in done.stderr and "Traceback" not in done.stderr
        assert re.search(r"simulator output file\(s\) .*stored\.csv", done.stderr)


def test_a_stored_path_is_read_only_when_named(series, tmp_path) -> None:
    frame = series.to_frame()[["time"]].copy()
    values = mechanistic(series.time_s)
    for j, name in enumerate(series.channels):
        frame[name] = values[:, j]
    csv = tmp_path / "sim.csv"
    frame.to_csv(csv, index=False)
    model = load_model(_parallel_with_stored_paths(series, tmp_path, [str(csv)]))
    with pytest.raises(ConfigError, match="--mechanistic"):
        model.predict_values(series)
    assert model.predict_values(series, MechanisticModel(csv)).shape == (len(series), 4)


@pytest.mark.parametrize("device", ["cuda", "cuda:3", "mps"])
def test_training_on_a_device_this_machine_lacks_is_refused_in_one_line(
    series, tmp_path, device
) -> None:
    """PyTorch had raised "Torch not compiled with CUDA enabled" from the first training step
    (a 77-line traceback); ``benchmark emps --device cuda`` likewise."""
    from drafttwin.models.training.compute import device_available

    if device_available(device):
        pytest.skip(f"this machine has {device}")
    data = write_measurements(series, tmp_path / "data.csv")
    result = CliRunner().invoke(app, ["fit", "--model", "gru", "--data", str(data), "--set",
                                      f"device={device}", "--quiet", "--out",
                                      str(tmp_path / "m.dtm")])  # fmt: skip
    assert result.exit_code == 2 and "Traceback" not in result.output, result.output
    assert f"training device --set device={device} is not on this machine" in result.output
    assert not (tmp_path / "m.dtm").exists()
    result = CliRunner().invoke(app, ["benchmark", "emps", "--device", device, "--seeds", "1",
                                      "--out", str(tmp_path / "e")])  # fmt: skip
    assert result.exit_code == 2 and "--device: device" in result.output, result.output
