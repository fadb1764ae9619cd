"""``sb3-pola score --out URL``: the storage layer, and runs into fsspec URLs against runs into a folder."""

from __future__ import annotations

import csv
import json
import pathlib
import uuid
from collections.abc import Iterator
from typing import Any

import pytest
import torch as th
from helpers import TINY_GRID, comparable

from sb3_pola.cli import score as score_cli
from sb3_pola.grid import cell as grid_cell
from sb3_pola.grid import rows as grid_rows
from sb3_pola.grid.storage import Storage, Workspace, open_workspace
from sb3_pola.pola import POLA

TINY = ["--steps", "6", "--eval-freq", "3", "--eval-episodes", "1", *TINY_GRID, "--datasets", "test/pendulum-v0"]


@pytest.fixture
def memory_url() -> Iterator[str]:
    """A fresh root of fsspec's in-process memory filesystem, deleted afterwards."""
    url = f"memory://sb3-pola-test-{uuid.uuid4().hex}/run"
    yield url
    storage = Storage(url)
    if storage.fs.exists(storage.root):
        storage.fs.rm(storage.root, recursive=True)


@pytest.fixture(params=["memory", "file"])
def url(request: pytest.FixtureRequest, memory_url: str, tmp_path: pathlib.Path) -> str:
    return memory_url if request.param == "memory" else (tmp_path / "store").as_uri()


def stored_rows(storage: Storage, tmp_path: pathlib.Path, rel: str = "scores.csv") -> list[dict[str, Any]]:
    local = tmp_path / "downloaded" / rel
    assert storage.get(rel, local)
    return grid_rows.read_rows(local)


def test_put_get_list_remove(url: str, tmp_path: pathlib.Path) -> None:
    storage = Storage(url)
    local = tmp_path / "a.csv"
    local.write_text("one")
    storage.put(local, "rows/a.csv")
    local.write_text("two")
    storage.put(local, "rows/a.csv")  # over the previous version
    assert storage.exists("rows/a.csv") and not storage.exists("rows/b.csv")
    assert storage.get("rows/a.csv", tmp_path / "back" / "a.csv") and (tmp_path / "back" / "a.csv").read_text() == "two"
    assert not storage.get("rows/b.csv", tmp_path / "back" / "b.csv") and not (tmp_path / "back" / "b.csv").exists()
    storage.put(local, "train/c/progress_from0.csv")
    assert storage.list("") == ["rows/a.csv", "train/c/progress_from0.csv"]  # temp files of the uploads are gone
    assert storage.list("train") == ["train/c/progress_from0.csv"] and storage.list("nothing") == []
    storage.remove("rows/a.csv")
    storage.remove("rows/a.csv")  # missing: nothing happens
    assert storage.list("rows") == []


def test_a_failed_upload_keeps_the_previous_file(url: str, tmp_path: pathlib.Path, monkeypatch: pytest.MonkeyPatch) -> None:
    storage = Storage(url)
    local = tmp_path / "ckpt.zip"
    local.write_bytes(b"first")
    storage.put(local, "ckpt/x.zip")
    local.write_bytes(b"second, never complete")

    def killed(*args: Any, **kwargs: Any) -> None:
        raise KeyboardInterrupt  # between the upload of the temp file and its move

    monkeypatch.setattr(storage.fs, "mv", killed)
    with pytest.raises(KeyboardInterrupt):
        storage.put(local, "ckpt/x.zip")
    monkeypatch.undo()
    assert storage.get("ckpt/x.zip", tmp_path / "back.zip") and (tmp_path / "back.zip").read_bytes() == b"first"
    # a temp file left by a process killed mid-upload is not listed
    storage.fs.pipe_file(f"{storage.root}/ckpt/.x.zip.0123.tmp", b"partial")
    assert storage.list("ckpt") == ["ckpt/x.zip"]


def test_workspace_pushes_what_changed(memory_url: str, tmp_path: pathlib.Path, monkeypatch: pytest.MonkeyPatch) -> None:
    storage = Storage(memory_url)
    view = Workspace(tmp_path / "scratch", storage)
    (tmp_path / "scratch" / "rows").mkdir(parents=True)
    (view.folder / "rows" / "a.csv").write_text("a")
    uploads: list[str] = []
    real_put = storage.put
    monkeypatch.setattr(storage, "put", lambda local, rel: (uploads.append(rel), real_put(local, rel)))
    view.push("rows/a.csv", "rows/missing.csv")
    view.push(view.folder / "rows" / "a.csv")  # unchanged: not uploaded again
    assert uploads == ["rows/a.csv"] and view.exists("rows/a.csv")
    (view.folder / "rows" / "a.csv").write_text("b")  # rewritten in place, same size (maybe the same mtime)
    view.push("rows/a.csv")
    assert uploads == ["rows/a.csv"] * 2
    other = Workspace(tmp_path / "other", storage)
    other.pull_tree("rows")
    other.push_tree("rows")  # just pulled: nothing to upload
    assert (other.folder / "rows" / "a.csv").read_text() == "b" and uploads == ["rows/a.csv"] * 2
    with open_workspace(memory_url) as scratch:
        assert scratch.storage is not None and scratch.location == memory_url and scratch.folder.is_dir()
    assert not scratch.folder.exists()  # the scratch folder is deleted
    with open_workspace(tmp_path / "plain") as local:  # a folder is its own storage: nothing is copied
        assert local.storage is None and local.folder == tmp_path / "plain" and local.folder.is_dir()
        local.pull("a.csv")
        assert not (local.folder / "a.csv").exists()
    monkeypatch.chdir(tmp_path)
    (tmp_path / "plain" / "cells").mkdir()
    (tmp_path / "plain" / "cells" / "x.json").write_text("{}")
    with open_workspace("plain") as relative:  # paths inside a folder given relative to the working directory
        assert relative.exists(relative.folder / "cells" / "x.json") and relative.exists("cells/x.json")
        assert not relative.exists(relative.folder / "cells" / "y.json")


def test_out_url_needs_its_backend(capsys: pytest.CaptureFixture) -> None:
    assert score_cli.main(["--out", "nosuchprotocol://bucket/score", "--ray"]) == 2
    assert "--out nosuchprotocol://bucket/score: Protocol not known" in capsys.readouterr().err


def _run(root: pathlib.Path, out: str | pathlib.Path, *extra: str) -> int:
    return score_cli.main([*TINY, "--data-dir", str(root), "--out", str(out), *extra])


def test_a_run_into_a_url_equals_a_run_into_a_folder(
    score_data: pathlib.Path, url: str, tmp_path: pathlib.Path, capsys: pytest.CaptureFixture
) -> None:
    folder = tmp_path / "folder"
    grid = ["--variants", "T0", "T1", "--seeds", "0"]
    assert _run(score_data, folder, *grid) == 0
    assert _run(score_data, url, *grid) == 0
    storage = Storage(url)
    expected = grid_rows.read_rows(folder / "scores.csv")
    assert len(expected) == 4 and comparable(stored_rows(storage, tmp_path)) == comparable(expected)
    names = [grid_rows.cell_name("test/pendulum-v0", v, 0) for v in ("T0", "T1")]
    files = set(storage.list(""))
    assert {f"cells/{n}.json" for n in names} | {f"models/{n}.zip" for n in names} <= files
    assert {"config.json", "table.md", "diagnostics.md", "fig_rollout_test_pendulum-v0.png"} <= files
    assert "dynamics/test_pendulum-v0__shared.pt" in files and not storage.list("ckpt")
    assert any(f.startswith(f"train/{names[1]}/progress_from0") for f in files)
    for name in names:  # the final models of the folder run, bit for bit
        assert storage.get(f"models/{name}.zip", tmp_path / "models" / f"{name}.zip")
        expected_state = POLA.load(folder / "models" / f"{name}.zip", device="cpu").policy.state_dict()
        state = POLA.load(tmp_path / "models" / f"{name}.zip", device="cpu").policy.state_dict()
        assert all(th.equal(state[key], value) for key, value in expected_state.items()), name
    # the same command again: both cells skipped; another configuration refused; the reports rewritten from the URL
    capsys.readouterr()
    assert _run(score_data, url, *grid, "-v", "1") == 0
    assert capsys.readouterr().out.count("done, skipped") == 2
    assert comparable(stored_rows(storage, tmp_path)) == comparable(expected)
    assert _run(score_data, url, *grid, "--steps", "9") == 2
    storage.remove("table.md")
    assert score_cli.main(["--report-only", "--out", url, "--variants", "T0", "T1"]) == 0
    assert storage.exists("table.md")
    assert score_cli.main(["--out", url, "--reevaluate", "ema", "-v", "0"]) == 0
    assert storage.get("reeval.csv", tmp_path / "reeval.csv") and storage.exists("reeval.md")
    with (tmp_path / "reeval.csv").open(newline="") as f:
        reeval = {r["variant"]: float(r["score"]) for r in csv.DictReader(f)}
    assert reeval == {r["variant"]: r["score"] for r in expected if r["step"] == 6}  # the final models' scores


def test_a_url_run_resumes_an_interrupted_cell(
    score_data: pathlib.Path, memory_url: str, tmp_path: pathlib.Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    cell = ["--variants", "T3-noproducts", "--seeds", "0", "--steps", "9"]
    folder = tmp_path / "folder"
    assert _run(score_data, folder, *cell) == 0
    real_evaluate = grid_cell.evaluate
    calls = []

    def interrupted(*args: Any, **kwargs: Any) -> Any:  # the second evaluation never happens: the process "dies" at step 6
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real_evaluate(*args, **kwargs)

    monkeypatch.setattr(grid_cell, "evaluate", interrupted)
    with pytest.raises(KeyboardInterrupt):
        _run(score_data, memory_url, *cell)
    storage = Storage(memory_url)
    name = grid_rows.cell_name("test/pendulum-v0", "T3-noproducts", 0)
    assert [r["step"] for r in stored_rows(storage, tmp_path, f"rows/{name}.csv")] == [3]
    assert storage.exists(f"ckpt/{name}.zip") and not storage.exists(f"cells/{name}.json")
    monkeypatch.setattr(grid_cell, "evaluate", real_evaluate)
    assert _run(score_data, memory_url, *cell) == 0
    rows = stored_rows(storage, tmp_path)
    assert comparable(rows) == comparable(grid_rows.read_rows(folder / "scores.csv"))
    assert rows[2]["wall_s"] >= rows[0]["wall_s"]
    assert storage.exists(f"train/{name}/progress_from3.csv")  # the resumed segment's statistics
    assert not storage.list("ckpt") and json.loads(storage.fs.cat_file(f"{storage.root}/cells/{name}.json"))["steps"] == 9
