"""Kept for code written against 1.0: ``from catmip_rl.checkpoint import load_model, save_model``. The
model files and checkpoints live in :mod:`catmip_rl.store.checkpoint`; start from ``catmip_rl.load_model``."""

from catmip_rl.store.checkpoint import load_model, save_model

__all__ = ["load_model", "save_model"]
