"""``sb3-pola score --ray``: a 2 x 2 grid on a local 2-CPU Ray instance against the sequential run (never ../shared)."""

from __future__ import annotations

import json
import os
import pathlib
import sys
from collections.abc import Iterator
from dataclasses import asdict
from typing import Any

import pytest
import torch as th
from helpers import SCORE_DATASETS, TINY_GRID, comparable, same_models

from sb3_pola.cli import score as score_cli
from sb3_pola.grid import cell as grid_cell
from sb3_pola.grid import ray_runner
from sb3_pola.grid import rows as grid_rows
from sb3_pola.grid import variants as grid_variants
from sb3_pola.pola import POLA

DATASETS = list(SCORE_DATASETS)
VARIANTS = ["T0", "T1"]
TINY = ["--steps", "20", "--eval-freq", "10", "--eval-episodes", "1", *TINY_GRID, "--threads", "1"]
TINY += ["--datasets", *DATASETS, "--variants", *VARIANTS, "--seeds", "0"]
# JSON {cell name: {"step": N, "action": "kill" | "raise"}}: read by the Ray workers' evaluations
FAULTS_ENV = "SB3_POLA_TEST_FAULTS"


def install_faults() -> None:
    """Ray worker setup hook: a cell of the faults file dies (``os._exit``, once) or raises at its evaluation of a step."""
    real_run_cell, real_evaluate = grid_cell.run_cell, grid_cell.evaluate
    current: dict[str, str] = {}

    def run_cell(dataset: str, variant: str, seed: int, *args: Any, **kwargs: Any) -> bool:
        current["cell"] = grid_rows.cell_name(dataset, variant, seed)
        return real_run_cell(dataset, variant, seed, *args, **kwargs)

    def evaluate(model: Any, *args: Any, **kwargs: Any) -> Any:
        path = pathlib.Path(os.environ[FAULTS_ENV])
        faults = json.loads(path.read_text()) if path.exists() else {}
        fault = faults.get(current.get("cell"))
        if fault is not None and fault["step"] == model.num_timesteps:
            if fault["action"] == "kill":
                del faults[current["cell"]]
                path.write_text(json.dumps(faults))
                os._exit(1)
            raise RuntimeError(f"injected failure at step {model.num_timesteps}")
        return real_evaluate(model, *args, **kwargs)

    grid_cell.run_cell, grid_cell.evaluate = run_cell, evaluate


@pytest.fixture(scope="module")
def local_ray(tmp_path_factory: pytest.TempPathFactory) -> Iterator[pathlib.Path]:
    """A local 2-CPU Ray instance whose workers run :func:`install_faults`; yields the faults file."""
    ray = pytest.importorskip("ray", reason="the tests extra installs ray")
    faults = tmp_path_factory.mktemp("faults") / "faults.json"
    tests = str(pathlib.Path(__file__).parent)
    path = os.pathsep.join([tests, *filter(None, [os.environ.get("PYTHONPATH")])])
    env_vars = {"PYTHONPATH": path, FAULTS_ENV: str(faults), "OMP_NUM_THREADS": "1"}
    niceness = autogroup_nice(0)
    try:
        ray.init(
            num_cpus=2,
            include_dashboard=False,
            log_to_driver=False,
            runtime_env={"worker_process_setup_hook": "test_ray_grid.install_faults", "env_vars": env_vars},
        )
    finally:
        autogroup_nice(niceness)
    # start both workers (their imports take a while) as the sequential run goes
    warm = [ray.remote(num_cpus=1)(warm_up).remote() for _ in range(2)]
    yield faults
    ray.get(warm)
    ray.shutdown()


def warm_up() -> None:
    """What a cell imports first."""
    import torch._dynamo  # noqa: F401  (the optimizers import it)

    import sb3_pola.pola  # noqa: F401


def autogroup_nice(value: int | None) -> int | None:
    """Set the niceness of this process's Linux autogroup (``None``: leave it); return the previous one.

    Ray's daemons must start within fixed deadlines (its agents within about 15 s), which a deprioritised test
    on a busy machine misses: they start at the normal priority, then share the tests' (where Linux allows it).
    """
    autogroup = pathlib.Path("/proc/self/autogroup")
    try:
        previous = int(autogroup.read_text().split()[-1])
        if value is not None and value != previous:
            autogroup.write_text(str(value))
    except (OSError, ValueError, IndexError):
        return None
    return previous


@pytest.fixture(scope="module")
def sequential(score_data: pathlib.Path, local_ray: pathlib.Path, tmp_path_factory: pytest.TempPathFactory) -> pathlib.Path:
    """The sequential run of the grid (while the Ray workers warm up), the reference of the Ray runs."""
    out = tmp_path_factory.mktemp("sequential") / "out"
    assert score_cli.main([*TINY, "--data-dir", str(score_data), "--out", str(out)]) == 0
    return out


# about 30 s on an idle 2-core machine; with other jobs holding the cores, Ray's workers (nice 15) get little CPU
# and it once needed more than the suite's 600 s, hence its own timeout
@pytest.mark.slow  # Ray workers; the cell task's side: test_a_cell_task_after_its_dynamics_fit_is_the_sequential_cell
@pytest.mark.timeout(1500)
def test_ray_grid_equals_sequential_and_recovers(
    score_data: pathlib.Path,
    local_ray: pathlib.Path,
    sequential: pathlib.Path,
    tmp_path: pathlib.Path,
    capsys: pytest.CaptureFixture,
) -> None:
    distributed = tmp_path / "ray"
    expected = grid_rows.read_rows(sequential / "scores.csv")
    assert len(expected) == 8  # 2 datasets x 2 variants x evaluations at steps 10 and 20

    # one worker dies after the cell's first evaluation, another cell raises: the other two cells finish
    killed, broken = (grid_rows.cell_name(d, "T1", 0) for d in DATASETS)
    local_ray.write_text(json.dumps({killed: {"step": 20, "action": "kill"}, broken: {"step": 10, "action": "raise"}}))
    command = [*TINY, "--data-dir", str(score_data), "--out", str(distributed), "--ray", "--max-retries", "0"]
    capsys.readouterr()
    assert score_cli.main(command) == 1
    err = capsys.readouterr().err
    assert f"{broken} failed" in err and "injected failure at step 10" in err
    assert f"{killed} failed" in err
    finished = {p.stem for p in (distributed / "cells").glob("*.json")}
    assert finished == {grid_rows.cell_name(d, "T0", 0) for d in DATASETS}
    assert sorted(p.name for p in (distributed / "dynamics").iterdir()) == [
        f"{grid_rows.slug(d)}__shared.pt" for d in DATASETS
    ]  # fitted once per dataset
    rows = grid_rows.read_rows(distributed / "scores.csv")
    assert [r["step"] for r in rows if grid_rows.cell_name(r["dataset"], r["variant"], r["seed"]) == killed] == [10]
    assert (distributed / "ckpt" / f"{killed}.zip").exists()

    # the same command again: finished cells skipped, the killed one continues from its checkpoint
    local_ray.write_text("{}")
    assert score_cli.main(command) == 0
    assert len(list((distributed / "cells").glob("*.json"))) == 4
    assert comparable(grid_rows.read_rows(distributed / "scores.csv")) == comparable(expected)
    assert "| test/pendulum2-v0 | T1 |" in (distributed / "table.md").read_text()
    assert (distributed / "fig_rollout_test_pendulum2-v0.png").exists()
    same_models(sequential / "models", distributed / "models")
    assert not list((distributed / "ckpt").glob("*.zip"))


@pytest.mark.slow  # Ray workers; the storage side: tests/test_storage.py
@pytest.mark.timeout(1500)
def test_ray_grid_into_a_url(
    score_data: pathlib.Path, local_ray: pathlib.Path, sequential: pathlib.Path, tmp_path: pathlib.Path
) -> None:
    """--out file://...: every worker in its own scratch folder; a worker killed mid-cell is retried from the storage."""
    from sb3_pola.grid.storage import Storage

    url = (tmp_path / "store").as_uri()
    killed = grid_rows.cell_name(DATASETS[0], "T1", 0)
    local_ray.write_text(json.dumps({killed: {"step": 20, "action": "kill"}}))  # once: the retry goes through
    grid = ["--datasets", DATASETS[0], "--max-retries", "1"]
    assert score_cli.main([*TINY, "--data-dir", str(score_data), "--out", url, "--ray", *grid]) == 0
    assert json.loads(local_ray.read_text()) == {}  # the worker did die (the fault is dropped just before)
    storage = Storage(url)
    local = tmp_path / "local"
    for rel in storage.list(""):
        assert storage.get(rel, local / rel)
    expected = [r for r in grid_rows.read_rows(sequential / "scores.csv") if r["dataset"] == DATASETS[0]]
    assert comparable(grid_rows.read_rows(local / "scores.csv")) == comparable(expected)
    assert (local / "train" / killed / "progress_from10.csv").exists()  # the retry continued from the step-10 checkpoint
    assert not storage.list("ckpt") and len(storage.list("cells")) == 2 and (local / "table.md").exists()
    expected_models = tmp_path / "expected"
    expected_models.mkdir()
    for path in (sequential / "models").glob(f"{grid_rows.slug(DATASETS[0])}__*.zip"):
        (expected_models / path.name).write_bytes(path.read_bytes())
    same_models(expected_models, local / "models")


def test_a_cell_task_after_its_dynamics_fit_is_the_sequential_cell(
    score_data: pathlib.Path, tmp_path: pathlib.Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The workers' side without Ray: the fit stops after step 1 with a checkpoint, the cell resumes from it."""
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(score_data))
    threads = th.get_num_threads()
    th.set_num_threads(1)
    try:
        config = grid_variants.build_config(score_cli.parse_args(TINY), "cpu")
        cell = (DATASETS[0], "T1", 0)
        name = grid_rows.cell_name(*cell)
        assert grid_cell.run_cell(*cell, config, tmp_path / "sequential", "cpu", verbose=0)
        out = tmp_path / "grid"
        common = (asdict(config), str(out), "cpu", 1, 0)
        assert ray_runner.cell_task(cell, *common, True, {}) is False
        assert grid_cell.dynamics_path(out, *cell[::2], config).exists() and (out / "ckpt" / f"{name}.zip").exists()
        assert grid_rows.read_rows(grid_rows.rows_path(out, cell)) == []
        assert ray_runner.cell_task(cell, *common, False, {}) is True
        assert ray_runner.cell_task(cell, *common, False, {}) is True  # finished: nothing is run again
    finally:
        th.set_num_threads(threads)
    rows = grid_rows.read_rows(grid_rows.rows_path(out, cell))
    assert [r["step"] for r in rows] == [10, 20]
    assert comparable(rows) == comparable(grid_rows.read_rows(tmp_path / "sequential" / "scores.csv"))
    expected = POLA.load(tmp_path / "sequential" / "models" / f"{name}.zip", device="cpu").policy.state_dict()
    state = POLA.load(out / "models" / f"{name}.zip", device="cpu").policy.state_dict()
    assert all(th.equal(state[key], value) for key, value in expected.items())


def test_missing_ray_says_which_extra(
    score_data: pathlib.Path, tmp_path: pathlib.Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray raises ImportError
    assert score_cli.main([*TINY, "--data-dir", str(score_data), "--out", str(tmp_path / "out"), "--ray"]) == 2
    err = capsys.readouterr().err
    assert 'sb3-pola score needs the "ray" extra: pip install "sb3_pola[ray]"' in err and "Traceback" not in err
    assert not (tmp_path / "out" / "scores.csv").exists()


def test_dynamics_fits_follow_the_sequential_order(tmp_path: pathlib.Path) -> None:
    cells = [(d, v, s) for s in (0, 1) for d in DATASETS for v in ("T0", "BC", "T3", "T1")]
    config = grid_variants.build_config(score_cli.parse_args(["--preset", "cpu"]), "cpu")
    fits = ray_runner.plan_dynamics_fits(cells, config, tmp_path)
    assert list(fits.values()) == [(d, "T3", 0) for d in DATASETS]
    config.share_dynamics = False
    fits = ray_runner.plan_dynamics_fits(cells, config, tmp_path)
    assert list(fits.values()) == [(d, "T3", s) for s in (0, 1) for d in DATASETS]
    path = grid_cell.dynamics_path(tmp_path, DATASETS[0], 0, config)
    path.parent.mkdir()
    path.write_bytes(b"")  # already fitted
    assert (DATASETS[0], "T3", 0) not in ray_runner.plan_dynamics_fits(cells, config, tmp_path).values()


def test_rows_of_the_cells_merge_into_scores_csv(tmp_path: pathlib.Path) -> None:
    def row(variant: str, step: int, value: float) -> dict[str, Any]:
        fields = dict(score_std=0.0, mean_return=0.0, eval_episodes=1, wall_s=1.0)
        return dict(dataset="d", variant=variant, seed=0, step=step, score=value, **fields)

    # a sequential run interrupted in T1, with a finished cell of another grid (T5)
    grid_rows.write_rows(tmp_path / "scores.csv", [row("T5", 10, 5.0), row("T1", 10, 1.0), row("T0", 10, 0.0)])
    cells = [("d", "T0", 0), ("d", "T1", 0)]
    grid_rows.adopt_rows(tmp_path, cells[1:])
    assert [r["score"] for r in grid_rows.read_rows(grid_rows.rows_path(tmp_path, cells[1]))] == [1.0]
    grid_rows.append_row(grid_rows.rows_path(tmp_path, cells[1]), row("T1", 20, 2.0))
    merged = grid_rows.collect_rows(tmp_path, cells)
    assert [(r["variant"], r["step"]) for r in merged] == [("T5", 10), ("T0", 10), ("T1", 10), ("T1", 20)]
    assert comparable(grid_rows.read_rows(tmp_path / "scores.csv")) == comparable(merged)
