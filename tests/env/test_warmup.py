"""The one-time compilation is announced, timed, recorded per sources and CPU, and not repeated."""

import io
from pathlib import Path

from catmip_env.runtime import warmup


def test_compile_once_announces_records_and_skips_the_second_time(tmp_path, monkeypatch):
    (tmp_path / "kernel.py").write_text("from numba import njit\n")
    calls = []
    out = io.StringIO()
    seconds = warmup.compile_once(tmp_path, "the kernels", lambda: calls.append(1), out)
    assert calls == [1] and seconds is not None and warmup.is_compiled(tmp_path)
    lines = out.getvalue().splitlines()
    assert lines[0] == "catmip: compiling the kernels, once on this machine..."
    assert lines[1].startswith("catmip: compiled the kernels in ") and lines[1].endswith(
        "(cached for later runs)"
    )
    assert warmup.compile_once(tmp_path, "the kernels", lambda: calls.append(2), out) is None and calls == [1]
    # an edited kernel source, or another CPU (numba's cache is per instruction set), compiles again
    (tmp_path / "kernel.py").write_text("from numba import njit  # edited\n")
    assert not warmup.is_compiled(tmp_path)
    warmup.compile_once(tmp_path, "the kernels", lambda: calls.append(3), None)
    assert calls == [1, 3] and warmup.is_compiled(tmp_path)
    monkeypatch.setattr(warmup, "_fingerprint", lambda package: "other cpu")
    assert not warmup.is_compiled(tmp_path)


def test_the_env_kernels_are_compiled_after_compile_kernels():
    warmup.compile_kernels(None)  # cached after the first run on this machine: seconds or nothing
    assert warmup.is_compiled(Path(warmup.__file__).parents[1])
