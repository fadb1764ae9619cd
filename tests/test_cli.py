"""The ``sb3-pola`` command line as a new user meets it: every command's ``--help``, the extras, the packaged config."""

from __future__ import annotations

import ast
import json
import os
import pathlib
import shutil
import subprocess
import sys
import zipfile

import pytest

import sb3_pola
from sb3_pola import cli
from sb3_pola.common import extras as extras_table
from sb3_pola.pola.pola import POLA

REPO = pathlib.Path(__file__).resolve().parent.parent
ALL_EXTRA_MODULES = sorted(set().union(*extras_table.EXTRA_MODULES.values()))


def run_cli(argv: list[str]) -> int:
    """``cli.main``'s exit status, also when the command exits through argparse (``--help``)."""
    try:
        return cli.main(argv)
    except SystemExit as error:
        return error.code if isinstance(error.code, int) else 1


def block(monkeypatch: pytest.MonkeyPatch, *modules: str) -> None:
    """Make ``import <module>`` (and its submodules) fail as if the module were not installed."""
    for module in modules:
        for name in [key for key in sys.modules if key.startswith(module + ".")]:
            monkeypatch.setitem(sys.modules, name, None)
        monkeypatch.setitem(sys.modules, module, None)


def extra_message(command: str, extra: str) -> str:
    return f'sb3-pola {command} needs the "{extra}" extra: pip install "sb3_pola[{extra}]"'


# ----------------------------------------------------------------------------- the mapping


def test_extras_are_setup_pys() -> None:
    """The dispatcher's extras exist in setup.py, under the distribution name it prints."""
    tree = ast.parse((REPO / "setup.py").read_text())
    call = next(node for node in ast.walk(tree) if isinstance(node, ast.Call) and getattr(node.func, "id", "") == "setup")
    keywords = {keyword.arg: keyword.value for keyword in call.keywords}
    assert ast.literal_eval(keywords["name"]) == extras_table.DISTRIBUTION
    extras = keywords["extras_require"]
    assert isinstance(extras, ast.Dict)
    names = {ast.literal_eval(key) for key in extras.keys if key is not None}
    assert set(extras_table.EXTRA_MODULES) <= names
    assert {extra for extras_ in extras_table.COMMAND_EXTRAS.values() for extra in extras_} <= set(extras_table.EXTRA_MODULES)
    assert set(extras_table.COMMAND_EXTRAS) <= set(cli.COMMANDS)


def test_missing_extra_follows_the_chain_of_causes() -> None:
    try:
        try:
            import onnxscript_not_installed_here  # noqa: F401
        except ModuleNotFoundError as error:
            error.name = "onnxscript.submodule"
            raise ImportError("ONNX export needs onnxscript") from error
    except ImportError as error:
        assert cli.missing_extra("export", error) == "export"
        assert cli.missing_extra("run", error) is None  # run has no extra: a real bug, not a missing extra
    assert cli.missing_extra("train", ModuleNotFoundError("x", name="some_other_module")) is None


def test_unknown_module_error_is_not_swallowed(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(cli.COMMANDS, "broken", ("sb3_pola_no_such_module", "a command whose module is missing"))
    with pytest.raises(ModuleNotFoundError):
        cli.main(["broken"])


# ----------------------------------------------------------------------------- help


def test_usage_names_the_extras(capsys: pytest.CaptureFixture) -> None:
    assert cli.main([]) == 0 and cli.main(["--help"]) == 0
    out = capsys.readouterr().out
    for name in cli.COMMANDS:
        assert f"  {name} " in out
    assert "train       rl-zoo3 train with POLA registered [extra: zoo]" in out
    assert cli.main(["no-such-command"]) == 2
    assert "unknown command 'no-such-command'" in capsys.readouterr().err


@pytest.mark.parametrize("command", list(cli.COMMANDS))
def test_every_command_has_help(command: str, capsys: pytest.CaptureFixture) -> None:
    if command in ("train", "enjoy", "optimize"):
        pytest.importorskip("rl_zoo3")
    assert run_cli([command, "--help"]) == 0
    out = capsys.readouterr().out
    assert "usage:" in out and len(out.splitlines()) > 3


HELP_WITHOUT_EXTRAS = """
import contextlib, io, json, sys
for name in {blocked!r}:
    sys.modules[name] = None
from sb3_pola.cli import main
results = {{}}
for command in {commands!r}:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main([command, "--help"])
        except SystemExit as error:
            code = error.code
    results[command] = [code, out.getvalue(), err.getvalue()]
print(json.dumps(results))
"""


def run_fresh(code: str) -> subprocess.CompletedProcess:
    """``code`` in a fresh interpreter on this worktree's package (nothing imported yet, as after ``pip install``)."""
    env = {**os.environ, "PYTHONPATH": str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""), "OMP_NUM_THREADS": "1"}
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=600)


def test_help_without_extras() -> None:
    """A plain install (no extras, all their modules blocked): every command shows its help, but the zoo's
    commands, which need rl-zoo3 for it, say which extra to install."""
    commands = list(cli.COMMANDS)
    result = run_fresh(HELP_WITHOUT_EXTRAS.format(blocked=ALL_EXTRA_MODULES, commands=commands))
    assert result.returncode == 0, result.stderr
    results = json.loads(result.stdout.splitlines()[-1])
    for command in commands:
        code, out, err = results[command]
        if command in ("train", "enjoy", "optimize"):
            assert code == 2 and err.startswith(extra_message(command, "zoo")), (command, err)
        else:
            assert code == 0 and "usage:" in out, (command, err)
        assert "Traceback" not in err


# ----------------------------------------------------------------------------- a missing extra says which


@pytest.mark.parametrize("command", ["train", "enjoy", "optimize"])
def test_zoo_commands_without_the_zoo_extra(command: str, capsys: pytest.CaptureFixture, monkeypatch) -> None:
    block(monkeypatch, "rl_zoo3")
    monkeypatch.delitem(sys.modules, "sb3_pola.zoo", raising=False)  # imported afresh, as in a new process
    assert cli.main([command, "--env", "a/b-v0"]) == 2
    err = capsys.readouterr().err
    assert err == f"{extra_message(command, 'zoo')} (missing module 'rl_zoo3')\n"


def test_train_help_without_yaml() -> None:
    """The issue's case: ``sb3-pola train --help`` after ``pip install .`` (rl-zoo3 installed, PyYAML not)."""
    result = run_fresh(
        "import sys\nsys.modules['yaml'] = None\nfrom sb3_pola.cli import main\nsys.exit(main(['train', '--help']))"
    )
    assert result.returncode == 2
    assert result.stderr.strip() == f"{extra_message('train', 'zoo')} (missing module 'yaml')"


@pytest.mark.parametrize("module", ["onnx", "onnxscript"])
def test_export_without_the_export_extra(
    module: str, tiny_dataset: str, tmp_path: pathlib.Path, capsys: pytest.CaptureFixture, monkeypatch
) -> None:
    model = POLA("MlpPolicy", dataset=tiny_dataset, seed=0, device="cpu", policy_kwargs={"net_arch": [8]})
    model.save(tmp_path / "model.zip")
    block(monkeypatch, module)
    assert cli.main(["export", str(tmp_path / "model.zip"), str(tmp_path / "policy.onnx")]) == 2
    err = capsys.readouterr().err
    assert extra_message("export", "export") in err and f"missing module {module!r}" in err and "Traceback" not in err
    assert not (tmp_path / "policy.onnx").exists()


def test_collect_maze_without_the_maze_extra(tmp_path: pathlib.Path, capsys: pytest.CaptureFixture, monkeypatch) -> None:
    block(monkeypatch, "gymnasium_robotics")
    argv = ["collect", "--env", "PointMaze_UMaze-v3", "--out", str(tmp_path), "--no-progress"]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert extra_message("collect", "maze") in err and "Traceback" not in err
    assert not any(tmp_path.iterdir())


def test_score_ray_without_the_ray_extra(tiny_dataset: str, tmp_path: pathlib.Path, capsys, monkeypatch) -> None:
    block(monkeypatch, "ray")
    argv = ["score", "--datasets", tiny_dataset, "--variants", "T0", "--seeds", "0", "--steps", "2"]
    assert cli.main([*argv, "--device", "cpu", "--out", str(tmp_path / "out"), "--ray"]) == 2
    err = capsys.readouterr().err
    assert extra_message("score", "ray") in err and "Traceback" not in err
    assert not (tmp_path / "out" / "scores.csv").exists()


def test_bench_section_without_the_export_extra(capsys: pytest.CaptureFixture, monkeypatch) -> None:
    from sb3_pola.benchmarks import bench, export_bench

    def run(quick: bool) -> None:
        import onnxruntime  # noqa: F401  (blocked below: the section's first need)

    monkeypatch.setattr(export_bench, "run", run)
    block(monkeypatch, "onnxruntime")
    result = bench.run_section("export", quick=True, device="cpu", policy_kwargs={}, compiled=False)
    err = capsys.readouterr().err
    assert result == {"skipped": f"{extra_message('bench', 'export')} (missing module 'onnxruntime')"}
    assert "Traceback" not in err and extra_message("bench", "export") in err


# ----------------------------------------------------------------------------- packaging: the zoo config


def test_default_config_is_package_data() -> None:
    """The launchers' default ``-conf`` lies inside the package and setup.py installs it."""
    pytest.importorskip("rl_zoo3")
    from sb3_pola import zoo

    config = zoo.default_config()
    package = pathlib.Path(sb3_pola.__file__).resolve().parent
    assert config.is_file() and config.resolve().parent.parent == package
    assert config.relative_to(package).as_posix() == "hyperparams/pola.yml"
    args = zoo.zoo_arguments("train", ["--env", "a/b-v0"])
    assert args[args.index("-conf") + 1] == str(config)
    # the repository's hyperparams/pola.yml (rl-zoo3's own -conf) is the same file
    assert (REPO / "hyperparams" / "pola.yml").resolve() == config.resolve()

    tree = ast.parse((REPO / "setup.py").read_text())
    package_data = next(
        ast.literal_eval(keyword.value)
        for node in ast.walk(tree)
        if isinstance(node, ast.Call)
        for keyword in node.keywords
        if keyword.arg == "package_data"
    )
    assert "hyperparams/*.yml" in package_data["sb3_pola"]


def test_wheel_contains_the_config(tmp_path: pathlib.Path) -> None:
    """A wheel built from a copy of the sources (offline: setuptools' own bdist_wheel) holds the config."""
    setuptools = pytest.importorskip("setuptools")
    if int(setuptools.__version__.split(".")[0]) < 70:
        pytest.skip("bdist_wheel without the wheel package needs setuptools >= 70.1")
    for name in ("setup.py", "README.md", "MANIFEST.in"):
        shutil.copy(REPO / name, tmp_path / name)
    shutil.copytree(REPO / "sb3_pola", tmp_path / "sb3_pola", ignore=shutil.ignore_patterns("__pycache__"))
    result = subprocess.run(
        [sys.executable, "setup.py", "-q", "bdist_wheel", "-d", "dist"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr
    assert "is absent from the `packages` configuration" not in result.stdout + result.stderr  # setuptools' warning
    (wheel,) = (tmp_path / "dist").glob("sb3_pola-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    assert "sb3_pola/hyperparams/pola.yml" in names
    assert "sb3_pola/version.txt" in names
    assert any(name.startswith("sb3_pola/data/datasets/invertedpendulum/medium-v0/") for name in names)
