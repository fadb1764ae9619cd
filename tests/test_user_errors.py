"""A user's mistakes get one line on stderr and exit status 2, the traceback only with ``--debug`` (issue #25)."""

from __future__ import annotations

import pathlib
import re

import pytest

from sb3_pola import cli
from sb3_pola.pola import POLA

TINY_MODEL = {"seed": 0, "device": "cpu", "policy_kwargs": {"net_arch": [8]}, "n_critics": 2}


def one_line_error(capsys: pytest.CaptureFixture, argv: list[str], debug: bool = False) -> str:
    """``sb3-pola <argv>``'s stderr, after checking the exit status 2 and the traceback's presence."""
    assert cli.main([*argv, *(["--debug"] if debug else [])]) == 2
    err = capsys.readouterr().err
    if debug:
        assert "Traceback (most recent call last)" in err
        return err.strip().splitlines()[-1]
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    return err.strip()


# ----------------------------------------------------------------------------- run's arguments


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["--steps", "0"], "argument --steps: must be an int >= 1, got 0"),
        (["--steps", "-5"], "argument --steps: must be an int >= 1, got -5"),
        (["--steps", "ten"], "argument --steps: must be an int >= 1, got 'ten'"),
        (["--eval-episodes", "0"], "argument --eval-episodes: must be an int >= 1"),
        (["--final-episodes", "-1"], "argument --final-episodes: must be an int >= 1"),
        (["--seed", "-1"], "argument --seed: must be an int >= 0"),
        (["--threads", "-2"], "argument --threads: must be an int >= 0"),
        (["--extra", "{bad"], "argument --extra: not valid JSON"),
        (["--extra", "[1, 2]"], "argument --extra: must be a JSON object"),
        (["--extra", '{"gama": 0.9}'], "--extra has unknown POLA argument(s) gama"),
        (["--extra", '{"gamma": 1.5}'], "gamma must be a number in (0.0, 1.0], got 1.5"),
        (["--extra", '{"batch_size": 0}'], "batch_size must be an int >= 1, got 0"),
        (["--config", "huge"], "argument --config: invalid choice: 'huge'"),
        (["--dataset", "nosuch"], "Unknown dataset 'nosuch': no such folder, and not a Minari dataset id"),
    ],
)
def test_run_bad_argument_one_line_and_nothing_written(
    argv: list[str], expected: str, tmp_path: pathlib.Path, capsys: pytest.CaptureFixture
) -> None:
    """Refused before anything is written: an existing model.zip of an earlier run is left as it was."""
    out = tmp_path / "main"
    out.mkdir()
    (out / "model.zip").write_bytes(b"an earlier run's model")
    line = one_line_error(capsys, ["run", "--out", str(out), *argv])
    assert line.startswith("sb3-pola run: error: ") and expected in line, line
    assert (out / "model.zip").read_bytes() == b"an earlier run's model"
    assert sorted(p.name for p in out.iterdir()) == ["model.zip"]


def test_debug_shows_the_traceback(capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch, tmp_path) -> None:
    line = one_line_error(capsys, ["run", "--out", str(tmp_path), "--dataset", "nosuch"], debug=True)
    assert "Unknown dataset 'nosuch'" in line
    monkeypatch.setenv("SB3_POLA_DEBUG", "1")
    assert cli.main(["run", "--out", str(tmp_path), "--dataset", "nosuch"]) == 2
    assert "Traceback (most recent call last)" in capsys.readouterr().err


# ----------------------------------------------------------------------------- model files, export, zoo


def test_model_file_errors_are_one_line(tmp_path: pathlib.Path, capsys: pytest.CaptureFixture) -> None:
    line = one_line_error(capsys, ["export", str(tmp_path / "fake.zip"), str(tmp_path / "p.onnx")])
    assert "No model file at" in line and "fake.zip" in line
    (tmp_path / "bad.zip").write_bytes(b"not a zip at all")
    line = one_line_error(capsys, ["export", str(tmp_path / "bad.zip"), str(tmp_path / "p.onnx")])
    assert "truncated or corrupt zip" in line
    assert not (tmp_path / "p.onnx").exists()


@pytest.mark.parametrize(
    ("out", "fmt", "expected"),
    [
        ("y.txt", None, "y.txt: the output must end in .onnx or .pt"),
        ("y.onnx", "torchscript", "y.onnx: the output must end in .pt or .pth"),
        ("y.pt", "onnx", "y.pt: the output must end in .onnx for --format onnx"),
    ],
)
def test_export_refuses_a_mismatched_extension(
    out: str, fmt: str | None, expected: str, tiny_dataset: str, tmp_path: pathlib.Path, capsys: pytest.CaptureFixture
) -> None:
    POLA("MlpPolicy", dataset=tiny_dataset, **TINY_MODEL).save(tmp_path / "model.zip")
    argv = ["export", str(tmp_path / "model.zip"), str(tmp_path / out), *(["--format", fmt] if fmt else [])]
    assert expected in one_line_error(capsys, argv)
    assert not (tmp_path / out).exists()


def test_zoo_unknown_env_is_one_line(capsys: pytest.CaptureFixture) -> None:
    pytest.importorskip("rl_zoo3")
    line = one_line_error(capsys, ["train", "--env", "nosuch/ds-v0"])
    assert "--env 'nosuch/ds-v0' is neither a local dataset nor a Gymnasium env" in line
    assert "invertedpendulum/medium-v0" in line  # the shipped datasets, as --env ids


# ----------------------------------------------------------------------------- --version, --help


def test_version(capsys: pytest.CaptureFixture) -> None:
    assert cli.main(["--version"]) == 0
    version = (pathlib.Path(cli.__file__).resolve().parent.parent / "version.txt").read_text().strip()
    assert capsys.readouterr().out == f"sb3-pola {version}\n"


@pytest.mark.parametrize("command", ["run", "datasets", "export", "score", "peers", "model-check"])
def test_help_shows_defaults_and_no_rest_markup(command: str, capsys: pytest.CaptureFixture) -> None:
    with pytest.raises(SystemExit):
        cli.main([command, "--help"])
    out = capsys.readouterr().out
    assert "``" not in out and not re.search(r":(func|class|mod|meth):", out), out
    if command == "run":
        assert "(default: 6000)" in out and "(default: invertedpendulum/medium-v0)" in out
