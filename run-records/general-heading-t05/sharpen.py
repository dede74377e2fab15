"""Divide a cell-goal AMAT's pointer logits by TAU through its weights (argmax unchanged): python sharpen.py SRC TAU DST"""
import sys
import torch

src, tau, dst = sys.argv[1], float(sys.argv[2]), sys.argv[3]
blob = torch.load(src, weights_only=False, map_location="cpu")
sd = blob["model"]
c = sd["query.3.weight"].shape[0]
for k in ("query.3.weight", "query.3.bias", "claimed"):
    sd[k] = sd[k] / tau
sd["cell_out.weight"][c] /= tau
sd["cell_out.bias"][c] /= tau
for k in ("optimizer",):
    blob.pop(k, None)
torch.save(blob, dst)
print("wrote", dst, "tau", tau)
