import sys, json
sys.path.insert(0, "/root/runs/sym/probe")
from oneview import OneView
import oneview
from catmip_rl.evaluation import execution
from catmip_rl.evaluation.evaluate import EvalSetting, evaluate
execution.Views = OneView
res = {}
for t in [int(x) for x in sys.argv[1:]]:
    oneview.T = t
    r = evaluate("amat:/root/runs/sym/general_v8.pt", EvalSetting("task2", "2", 0.0, 10), 200, 7001, sampled_too=False)
    res[t] = r.summary["success_by_100"]; print(t, res[t], flush=True)
