"""Shared test helpers for catmip_rl."""

import torch

from catmip_rl.amat.pointer import make_model


def shaken_model(config=None, seed=0, scale=0.2):
    """A model whose weights are far from the tiny-gain init, so that attention and the heads really mix
    (the window or the cell-goal model, as ``config`` says)."""
    torch.manual_seed(seed)
    m = make_model(config)
    with torch.no_grad():
        for p in m.parameters():
            p.add_(scale * torch.randn_like(p))
    return m.eval()


def one_line_error(capsys, *needles: str) -> str:
    """What the command printed on stderr: one line, no traceback, holding every needle."""
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    for needle in needles:
        assert needle in err, (needle, err)
    return err
