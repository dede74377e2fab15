#!/bin/bash
# device check (issue 37): CUDA tests at HEAD, then the general-heading recipe's iteration times on the GPU
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl || exit 1
export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv | tee $OUT/env.txt
nproc | tee -a $OUT/env.txt
python3 -c "import torch,torchrl,tensordict,numba; print('torch',torch.__version__,'torchrl',torchrl.__version__,'tensordict',tensordict.__version__,'numba',numba.__version__,torch.cuda.get_device_name())" 2>&1 | tee -a $OUT/env.txt
timeout 240 python3 -m pytest -q -p no:cacheprovider tests/rl/training/test_cuda.py 2>&1 | tail -25 | tee $OUT/tests.txt
for mb in 0; do
  timeout 300 python3 -m catmip_rl.cli.main train --preset general-heading --init-from .whl/start.pt \
    --run-dir /tmp/g$mb --device cuda --threads 16 --iterations 6 --micro-batch $mb --no-progress \
    --set value_warmup_iterations=0 --set eval_every=0 --set checkpoint_every=0 2>&1 | tail -15
  cp /tmp/g$mb/metrics.csv $OUT/metrics_mb$mb.csv; cp /tmp/g$mb/config.json $OUT/config_mb$mb.json
done
ls /tmp/g0
