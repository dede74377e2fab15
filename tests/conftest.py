import os
import sys

import pytest

os.environ.setdefault("MPLBACKEND", "Agg")
# pytest -n 2 runs two workers on a 2-core machine: one torch thread each avoids oversubscription
os.environ.setdefault("OMP_NUM_THREADS", "1")


@pytest.fixture(autouse=True)
def _restore_torch_threads():
    """Tests that run the CLI or ``train`` in-process set torch's thread count; restore it so that the
    tests after them in the same worker run as they would alone."""
    torch = sys.modules.get("torch")  # the env tests never import torch
    before = torch.get_num_threads() if torch is not None else None
    yield
    torch = sys.modules.get("torch")
    if torch is not None and before is not None and torch.get_num_threads() != before:
        torch.set_num_threads(before)
