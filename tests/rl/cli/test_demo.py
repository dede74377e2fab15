"""The README's ``make demo`` (catmip_rl.cli.demo) on a tiny budget: every promised row and file."""

import csv

import pytest

from catmip_rl.cli import demo


@pytest.mark.slow
def test_demo_table_has_the_trained_and_shipped_models_and_the_planners(tmp_path, capsys):
    rows = demo.main(["--iterations", "1", "--episodes", "2", "--warm-start-rounds", "1", "--worlds", "4",
                      "--planners", "nearest", "--threads", "1", "--out", str(tmp_path)])  # fmt: skip
    names = [r["method"] for r in rows]
    assert names == ["AMAT (demo, 1 it)", "AMAT (shipped)", "nearest", "window:nearest"]
    with open(tmp_path / "results.csv") as f:
        assert [r["method"] for r in csv.DictReader(f)] == names
    assert "| AMAT (shipped) |" in (tmp_path / "results.md").read_text()
    assert "AMAT (shipped)" in capsys.readouterr().out
    for figure in ("success.png", "episode.gif"):
        assert (tmp_path / figure).stat().st_size > 1000


def test_demo_fails_loudly_without_the_shipped_model(tmp_path, monkeypatch):
    def missing(name):
        raise FileNotFoundError(f"AMAT model {name!r} does not exist")

    monkeypatch.setattr(demo, "resolve_model", missing)
    with pytest.raises(FileNotFoundError):
        demo.main(["--out", str(tmp_path)])
    assert not (tmp_path / "train").exists()  # nothing trained before the error
