"""The figures: a setting's title ("Task 2, σ = 2, 5 % noise") wherever a figure names one, compare's
success-vs-time curves per setting with 95 % bands, paired.png's title and legend, palette PNGs."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

pytest.importorskip("matplotlib")

from PIL import Image  # noqa: E402

from catmip_rl.benchmark.compare import compare  # noqa: E402
from catmip_rl.benchmark.results import load_results  # noqa: E402
from catmip_rl.evaluation import plots  # noqa: E402
from catmip_rl.evaluation.evaluate import EvalSetting  # noqa: E402
from catmip_rl.evaluation.plots import setting_title  # noqa: E402


@pytest.mark.parametrize(
    "setting, title",
    [
        (EvalSetting("task2", "2", 0.05), "Task 2, σ = 2, 5 % noise"),
        (EvalSetting("task1"), "Task 1, full communication"),
        (EvalSetting("task3", "4"), "Task 3, σ = 4"),
        (EvalSetting("task2", "full", 0.0, 20), "Task 2, full communication, macro-actions ≤ 20 ticks"),
        ("task2-sigma2-noise0.05-ma10", "Task 2, σ = 2, 5 % noise"),  # a label as summary.json holds it
        ("task3-sigma4-noise0.025-ma5", "Task 3, σ = 4, 2.5 % noise, macro-actions ≤ 5 ticks"),
        ("sigma = 4", "sigma = 4"),  # a panel already named (the paper figures'): as it is
        ("task2-x", "task2-x"),
    ],
)
def test_a_setting_is_titled_in_words(setting, title):
    assert setting_title(setting) == title
    if isinstance(setting, EvalSetting):
        assert setting.title == title and setting_title(setting.label) == title


@pytest.fixture
def drawn(monkeypatch):
    """The figures the plots would save, kept open for reading (atomic_savefig saves and closes them)."""
    import matplotlib.pyplot as plt

    figures = []

    def keep(fig, path, dpi=110):
        figures.append(fig)
        return Path(path)

    monkeypatch.setattr(plots, "atomic_savefig", keep)
    yield figures
    for fig in figures:
        plt.close(fig)


def _write(folder: Path, method: str, ticks: list[int | None], label: str, first_map: int = 0) -> None:
    folder.mkdir(parents=True)
    rows = [{"map_hash": f"{first_map + e:08x}", "rescue_tick": t} for e, t in enumerate(ticks)]
    (folder / "episodes.json").write_text(json.dumps(rows))
    (folder / "summary.json").write_text(
        json.dumps({"method": method, "label": label, "horizon": 300, "seed": 0})
    )


LABELS = ("task1-full-noise0-ma10", "task2-sigma2-noise0.05-ma10")


def _results(tmp_path: Path, runs: bool = True):
    """Two settings, methods a and b and (``runs``) c with two training runs, all on the same maps."""
    for k, label in enumerate(LABELS):
        _write(tmp_path / label / "a", "a", [40] * 30 + [None] * 10, label, 100 * k)
        _write(tmp_path / label / "b", "b", [80] * 20 + [200] * 10 + [None] * 10, label, 100 * k)
        _write(tmp_path / label / "c", "c-seed0", [60] * 25 + [None] * 15, label, 100 * k)
        _write(tmp_path / label / "c1", "c-seed1", [70] * 20 + [None] * 20, label, 100 * k)
    specs = [str(tmp_path / label / m) for label in LABELS for m in ("a", "b")]
    if runs:
        specs.append("c=" + ",".join(str(tmp_path / label / m) for label in LABELS for m in ("c", "c1")))
    return load_results(specs)


def test_compare_overlays_every_methods_curve_with_its_band_per_setting(tmp_path, monkeypatch):
    report = compare(_results(tmp_path / "r"))
    rows = [r for r in report.curves if r["panel"] == LABELS[0] and r["method"] == "a"]
    assert [r["tick"] for r in rows] == list(range(301))  # every tick to the horizon
    assert rows[39]["success_rate"] == 0 and rows[40]["success_rate"] == pytest.approx(0.75)
    assert rows[40]["ci_low"] < 0.75 < rows[40]["ci_high"]  # a 95 % band over the maps
    c = [r for r in report.curves if r["panel"] == LABELS[0] and r["method"] == "c"]
    assert (
        c[-1]["success_rate"] == pytest.approx((25 + 20) / 80) and c[-1]["runs"] == 2
    )  # the mean of its runs
    written = report.write(tmp_path / "out")
    pngs = {p.name for p in written if p.suffix == ".png"}
    assert {"curves.png", "paired.png", "aggregate.png", "profile.png"} <= pngs
    for name in pngs:
        with Image.open(tmp_path / "out" / name) as image:
            assert image.mode == "P", name  # saved by atomic_savefig: 256 colours
    assert (tmp_path / "out" / "curves.csv").read_text().startswith("panel,method,runs,tick,success_rate")
    drawn = []
    monkeypatch.setattr(plots, "atomic_savefig", lambda fig, path: drawn.append(fig))
    plots.plot_curves(report.curves, tmp_path / "curves.png", "Success rate vs mission time")
    (curves,) = drawn
    axes = [ax for ax in curves.axes if ax.get_visible()]
    assert [ax.get_title() for ax in axes] == ["Task 1, full communication", "Task 2, σ = 2, 5 % noise"]
    for ax in axes:  # one line and one band per method
        assert len(ax.get_lines()) == 3 and len(ax.collections) == 3
    (legend,) = curves.legends
    assert [t.get_text() for t in legend.get_texts()] == ["a", "b", "c (mean of 2 runs)"]


def test_paired_png_has_a_title_a_legend_and_settings_in_words(tmp_path, drawn):
    report = compare(_results(tmp_path / "r", runs=False))
    plots.plot_paired(report.paired, tmp_path / "paired.png")
    (fig,) = drawn
    (ax,) = fig.axes
    assert ax.get_title() == "Paired per-map differences in success by tick 100 (A − B)"
    labels = [t.get_text() for t in ax.get_yticklabels()]
    assert labels[0] == "Task 1, full communication" and "Task 2, σ = 2, 5 % noise" in labels
    assert "a − b" in labels and not any("task1-" in t for t in labels)
    (legend,) = fig.legends
    texts = [t.get_text() for t in legend.get_texts()]
    assert texts == [text for _, _, text in plots.PAIRED_KINDS] and len(texts) == 3


def test_the_eval_curve_titles_its_setting_in_words(tmp_path, drawn):
    rows = [{"panel": "task3-sigma4-noise0.05-ma10", "method": "m", "tick": t, "success_rate": t / 10,
             "ci_low": 0.0, "ci_high": 1.0} for t in range(11)]  # fmt: skip
    plots.plot_curves(rows, tmp_path / "curve.png", title="10 maps (seed 0)")
    (fig,) = drawn
    assert (
        fig.axes[0].get_title() == "Task 3, σ = 4, 5 % noise"
        and fig._suptitle.get_text() == "10 maps (seed 0)"
    )
