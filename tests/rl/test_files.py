"""Atomic result files (catmip_env.runtime.files, catmip_rl.store.files): whole files or nothing, nothing left
behind."""

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt
import numpy as np
import pytest

from catmip_env.runtime.files import atomic_path
from catmip_rl.store.files import atomic_savefig, atomic_write_text


def test_an_error_while_writing_leaves_the_old_file_and_no_temporary(tmp_path):
    target = atomic_write_text(tmp_path / "result.csv", "old\n")
    with pytest.raises(RuntimeError), atomic_path(target) as tmp:
        tmp.write_text("half a fi")
        raise RuntimeError("crash mid-write")
    assert target.read_text() == "old\n" and sorted(p.name for p in tmp_path.iterdir()) == ["result.csv"]


def test_two_writers_of_one_file_get_their_own_temporaries(tmp_path):
    with atomic_path(tmp_path / "a.png") as one, atomic_path(tmp_path / "a.png") as two:
        assert one != two and one.suffix == two.suffix == ".png" and one.name.startswith(".a.")
        one.write_text("first")
        two.write_text("second")
    assert (tmp_path / "a.png").read_text() == "first"  # the last rename wins, a whole file
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.png"]


def test_a_figure_is_saved_whole_and_closed(tmp_path):
    fig, ax = plt.subplots()
    ax.plot([0, 1], [1, 0])
    png = atomic_savefig(fig, tmp_path / "sub" / "curve.png", dpi=50)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and not plt.fignum_exists(fig.number)
    assert sorted(p.name for p in png.parent.iterdir()) == ["curve.png"]


def test_a_png_figure_is_a_palette_image_of_the_same_picture(tmp_path):
    """256 colours: the committed figures take a third of the bytes, and the picture is the same."""
    from PIL import Image

    def figure():
        fig, ax = plt.subplots()
        ax.fill_between([0, 1, 2], [0, 0.5, 0.2], [0.3, 0.9, 0.6], alpha=0.3)
        ax.plot([0, 1, 2], [0.1, 0.7, 0.4], label="a line")
        ax.legend()
        return fig

    png = atomic_savefig(figure(), tmp_path / "small.png", dpi=80)
    figure().savefig(tmp_path / "full.png", dpi=80, facecolor="white")
    small, full = Image.open(png), Image.open(tmp_path / "full.png")
    assert small.mode == "P" and small.size == full.size
    diff = np.abs(np.asarray(small.convert("RGB"), float) - np.asarray(full.convert("RGB"), float))
    assert diff.mean() < 1.0 and np.percentile(diff, 99.9) < 40  # the same picture, a colour off at most
    assert png.stat().st_size < 0.6 * (tmp_path / "full.png").stat().st_size
