"""average.py OUT IN1 IN2 ...: the uniform average of the weights of training checkpoints or model files
of one architecture (the seventh sitting's weight averages; docs/notes/general-model.md)."""

import sys

import torch


def load(path: str) -> dict:
    blob = torch.load(path, weights_only=False, map_location="cpu")
    if "state_dict" in blob:  # a model file (catmip export): weights and config
        blob = {"amat_config": blob["config"], "model": blob["state_dict"]}
    return blob


def same_architecture(a: dict, b: dict) -> bool:
    return {k: v for k, v in a.items() if k != "critic"} == {k: v for k, v in b.items() if k != "critic"}


out, sources = sys.argv[1], sys.argv[2:]
blobs = [load(p) for p in sources]
for path, blob in zip(sources, blobs, strict=True):
    assert same_architecture(blob["amat_config"], blobs[0]["amat_config"]), path
average = {}
for key, value in blobs[0]["model"].items():
    if torch.is_floating_point(value):
        average[key] = sum(b["model"][key].double() for b in blobs).div(len(blobs)).to(value.dtype)
    else:
        assert all(torch.equal(b["model"][key], value) for b in blobs), key
        average[key] = value
torch.save({**blobs[0], "model": average, "iteration": 0}, out)
print(out, len(sources), "runs averaged")
