"""Build the API reference (HTML, from the docstrings) with pdoc:

    python docs/build_api.py [--out docs/api]        # or: make api

Every module of ``catmip_env`` and ``catmip_rl`` gets a page (``OUT/index.html`` lists them). The output
is generated, not committed; ``tests/test_api_reference.py`` builds it and checks its links.
"""

from __future__ import annotations

import argparse
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def module_names(root: Path = ROOT) -> list[str]:
    """The modules to document: every module of catmip_env (a flat package whose ``__all__`` would hide
    them), catmip_rl's top-level modules and its sub-packages (pdoc walks those itself)."""
    names = ["catmip_env", "catmip_rl"]
    for pkg in ("catmip_env", "catmip_rl"):
        for path in sorted((root / pkg).iterdir()):
            if path.suffix == ".py" and path.stem not in ("__init__", "__main__"):
                names.append(f"{pkg}.{path.stem}")
            elif path.is_dir() and (path / "__init__.py").exists():
                names.append(f"{pkg}.{path.name}")
    return names


def build(out: Path) -> Path:
    """Write the reference into ``out``; returns ``out / "index.html"``."""
    import warnings

    import pdoc
    import pdoc.render

    pdoc.render.configure(docformat="restructuredtext", search=True, show_source=True)
    with warnings.catch_warnings():  # NamedTuple fields annotated "np.ndarray": shown as written
        warnings.filterwarnings("ignore", "Error parsing type annotation", UserWarning)
        pdoc.pdoc(*module_names(), output_directory=Path(out))
    return Path(out) / "index.html"


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "api", help="output folder")
    args = ap.parse_args(argv)
    print(f"wrote {build(args.out)}")


if __name__ == "__main__":
    main()
