"""MAPPO or IPPO on the native TorchRL env, built from TorchRL's own parts, trained on any task, saved as a
policy that ``catmip eval`` plays on the paper's protocol. The recipe of TorchRL's
``sota-implementations/multiagent/mappo_ippo.py`` on ``catmip_rl.adapters.torchrl_env.CatmipEnv``:

* ``TransformedEnv(CatmipEnv, float_observation_transform() + RewardSum)``, one step = one decision
  event in every world;
* a shared policy (a small CNN over each robot's float maps) as a ``ProbabilisticActor`` with a
  ``MaskedCategorical`` over the action mask; a critic that is centralised (MAPPO: the world's ground
  truth beside the robot's own map) or not (IPPO: the robot's own maps);
* ``Collector``; the asynchronous advantage (``torchrl_marl.decision_samples``): TorchRL's GAE along each
  robot's *own* decisions with the discount ``gamma ** ticks`` between them, only finished
  macro-actions trained; ``ClipPPOLoss`` on those per-robot samples from a ``ReplayBuffer``.

    python examples/mappo_torchrl.py --algo mappo --task task1 --minutes 20 --out runs/mappo-task1-s0
    python examples/mappo_torchrl.py --algo ippo --task task2 --seed 1 --minutes 30 --out runs/ippo-task2-s1

``--out`` gets ``metrics.csv`` (per iteration), ``config.json``, ``policy.pt`` (weights only, saved every
``--save-every`` iterations and at the end), ``policy.json`` and ``policy.py``, a factory for
``catmip eval --task TASK --method mappo=py:OUT/policy.py:make_policy``; ``state.pt``, what
``--resume`` needs (weights, optimiser, iteration, minutes spent, the sampling RNG): keep it out of
a repository; and ``weights.pt``, the actor's and critic's weights in half precision with the
iteration (a snapshot small enough to commit while a run spans several sittings).

    python examples/mappo_torchrl.py --resume --out runs/ippo-task2-s1   # after an interruption
    python examples/mappo_torchrl.py --resume --from-weights --out runs/ippo-task2-s1   # state.pt lost

A resumed run goes on from its last save with the options in ``OUT/config.json``; its worlds start
new episodes (drawn from the seed and the iteration, so not the maps played before), which costs
the episodes that were in progress. ``--from-weights`` continues from ``weights.pt`` alone, with a
new optimiser (its moments start again from zero). At the end the policy is
evaluated on the task's protocol maps (``--eval-episodes``, seed ``--eval-seed``) beside Nearest and
``random-uniform``, through that factory.
"""

from __future__ import annotations

import argparse
import csv
import json
import time
from pathlib import Path

import numpy as np
import torch
from torch import nn
from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, ReplayBuffer, SamplerWithoutReplacement
from torchrl.envs import Compose, RewardSum, TransformedEnv
from torchrl.objectives import ClipPPOLoss

from catmip_env import PRESETS, make_config
from catmip_rl.adapters import keys as K
from catmip_rl.adapters.torchrl_env import CatmipEnv, float_observation_transform
from catmip_rl.adapters.torchrl_marl import (
    ADVANTAGE,
    ALGOS,
    VALUE_TARGET,
    decision_samples,
    load_policy,
    make_actor,
    make_critic,
    save_policy,
)
from catmip_rl.store.checkpoint import atomic_torch_save
from catmip_rl.store.files import atomic_write_csv, atomic_write_text

EPISODE_REWARD = (K.ROBOTS, "episode_reward")
STATE = "state.pt"  # what --resume needs; policy.pt holds the actor's weights alone
WEIGHTS = "weights.pt"  # actor and critic in half precision: what --resume --from-weights needs


def make_env(task: str, num_worlds: int, seed: int) -> TransformedEnv:
    """The task's world (training activation, a new map every episode) with float maps and episode returns."""
    base = CatmipEnv(make_config(task), num_worlds=num_worlds, seed=seed)
    return TransformedEnv(
        base, Compose(float_observation_transform(), RewardSum(in_keys=[K.REWARD], out_keys=[EPISODE_REWARD]))
    )


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--algo", default="mappo", choices=ALGOS, help="centralised (mappo) or local (ippo) critic"
    )
    ap.add_argument("--task", default="task1", choices=sorted(PRESETS), help="the world trained on")
    ap.add_argument(
        "--minutes",
        type=float,
        default=None,
        help="wall-clock budget (the LR decays over it); 5 without --iterations",
    )
    ap.add_argument(
        "--iterations", type=int, default=None, help="budget in iterations (no time limit unless --minutes)"
    )
    ap.add_argument("--worlds", type=int, default=32, help="worlds stepped together")
    ap.add_argument("--events", type=int, default=64, help="events per world per iteration")
    ap.add_argument("--epochs", type=int, default=4)
    ap.add_argument("--minibatch", type=int, default=256, help="robot decisions per minibatch")
    ap.add_argument("--lr", type=float, default=3e-4)
    ap.add_argument("--gamma", type=float, default=0.99, help="discount per tick")
    ap.add_argument("--lmbda", type=float, default=0.95)
    ap.add_argument("--entropy", type=float, default=0.01, help="entropy bonus")
    ap.add_argument("--reward-scale", type=float, default=0.01)
    ap.add_argument("--seed", type=int, default=0, help="training seed (worlds, sampling, initial weights)")
    ap.add_argument("--pool", type=int, default=4, help="the CNN's output pooled to POOL x POOL: any map "
                    "size; 0: flattened, the task's map size only (the recorded Task 1/2 runs)")  # fmt: skip
    ap.add_argument("--init-from", default=None, metavar="POLICY.pt", help="start the actor from a saved "
                    "policy (e.g. a Task-2 run's, to train on Task 3); the critic starts new")  # fmt: skip
    ap.add_argument("--critic-warmup", type=int, default=0, help="first iterations that train the critic "
                    "alone (with --init-from: advantages from a critic that knows the policy)")  # fmt: skip
    ap.add_argument("--threads", type=int, default=1, help="torch threads")
    ap.add_argument("--out", default=None, help="run folder (new or empty): metrics, config, policy files")
    ap.add_argument("--save-every", type=int, default=20, help="iterations between policy saves")
    ap.add_argument(
        "--eval-episodes", type=int, default=100, help="protocol maps evaluated at the end (0: none)"
    )
    ap.add_argument("--eval-seed", type=int, default=0, help="the map set of that evaluation")
    ap.add_argument(
        "--resume", action="store_true", help="continue the run in --out from its last save, with its options"
    )
    ap.add_argument("--from-weights", action="store_true", help=f"with --resume: from OUT/{WEIGHTS} "
                    f"(weights only, a new optimiser) when OUT/{STATE} is lost")  # fmt: skip
    args = ap.parse_args(argv)
    if args.from_weights and not args.resume:
        ap.error("--from-weights goes with --resume: it continues a run from its weights-only snapshot")
    if args.resume:
        defaults = ap.parse_args([])
        fixed = ("resume", "from_weights", "out")
        given = sorted(k for k, v in vars(args).items() if k not in fixed and v != getattr(defaults, k))
        if given:  # never ignored in silence: the run's options are its config.json's
            ap.error(f"--resume continues with the run's own options (OUT/config.json), not {given}: "
                     "edit config.json to change them")  # fmt: skip
        return _saved_args(ap, defaults, args.out, args.from_weights)
    if args.minutes is None and args.iterations is None:
        args.minutes = 5.0
    return args


def _saved_args(
    ap: argparse.ArgumentParser, args: argparse.Namespace, out: str | None, from_weights: bool
) -> argparse.Namespace:
    """``args`` (the defaults) updated with the options of the run in ``out`` (its config.json), marked
    to resume; one line when there is nothing to resume from."""
    if out is None:
        ap.error("--resume needs --out: the run folder to continue")
    folder = Path(out)
    source = WEIGHTS if from_weights else STATE
    if not (folder / source).is_file() or not (folder / "config.json").is_file():
        hint = (f"; it has {WEIGHTS}: add --from-weights to continue from the weights with a new optimiser"
                if not from_weights and (folder / WEIGHTS).is_file() else "")  # fmt: skip
        ap.error(f"--resume: {folder} holds no {source} and config.json (nothing saved to continue "
                 f"from){hint}")  # fmt: skip
    saved = json.loads((folder / "config.json").read_text())
    unknown = set(saved) - set(vars(args))
    if unknown:
        ap.error(f"--resume: {folder}/config.json has options this script does not know: {sorted(unknown)}")
    vars(args).update(saved, resume=True, from_weights=from_weights)
    return args


def _spent(args: argparse.Namespace, minutes: float, iterations: int) -> float:
    """The fraction of the budget spent: of whichever of --minutes / --iterations ends first."""
    return max(
        minutes / args.minutes if args.minutes else 0.0,
        iterations / args.iterations if args.iterations else 0.0,
    )


def main(argv: list[str] | None = None) -> list[dict[str, float]]:
    args = parse_args(argv)
    torch.set_num_threads(args.threads)
    torch.manual_seed(args.seed)
    out = Path(args.out) if args.out else None
    if out is not None and not args.resume and out.exists() and any(out.iterdir()):
        raise SystemExit(f"--out {out} is not empty: pick a new folder, or continue it with --resume")
    cfg = make_config(args.task)

    actor = make_actor(cfg, pool=args.pool)
    critic = make_critic(cfg, args.algo, pool=args.pool)
    loss_module = ClipPPOLoss(
        actor, critic, clip_epsilon=0.2, entropy_coeff=args.entropy, loss_critic_type="l2"
    )
    loss_module.set_keys(action=K.ACTION, sample_log_prob=K.LOG_PROB, value=K.VALUE, advantage=ADVANTAGE,
                         value_target=VALUE_TARGET)  # fmt: skip
    optim = torch.optim.Adam(loss_module.parameters(), args.lr)
    first, spent_minutes, history = _start(args, cfg, out, actor, critic, optim)
    env = make_env(args.task, args.worlds, _world_seed(args.seed, first))
    frames_per_batch = args.worlds * args.events
    # return_same_td: the batch is used up (its decisions copied to the buffer) before the next is
    # collected, so the collector need not clone it (~1 s an iteration of Task 3's float maps)
    collector = Collector(env, actor, frames_per_batch=frames_per_batch, total_frames=-1,
                          auto_register_policy_transforms=False, return_same_td=True)  # fmt: skip
    # at most every robot decides at every event of the batch
    buffer = ReplayBuffer(storage=LazyTensorStorage(frames_per_batch * cfg.num_robots),
                          sampler=SamplerWithoutReplacement(), batch_size=args.minibatch)  # fmt: skip
    if out is not None and not args.resume:
        out.mkdir(parents=True, exist_ok=True)
        options = {k: v for k, v in vars(args).items() if k not in ("resume", "from_weights")}
        atomic_write_text(out / "config.json", json.dumps(options, indent=2))
    start = time.perf_counter() - 60 * spent_minutes
    for iteration, data in enumerate(collector, start=first):
        minutes = (time.perf_counter() - start) / 60
        for group in optim.param_groups:  # linear decay over whichever budget ends first
            group["lr"] = args.lr * max(0.0, 1 - _spent(args, minutes, iteration))
        data.set(("next", *K.REWARD), data.get(("next", *K.REWARD)) * args.reward_scale)
        samples = decision_samples(data, critic, args.gamma, args.lmbda)
        adv = samples.get(ADVANTAGE)
        samples.set(ADVANTAGE, (adv - adv.mean()) / (adv.std() + 1e-8))
        buffer.empty()
        buffer.extend(samples)
        for _ in range(args.epochs * max(1, len(samples) // args.minibatch)):
            losses = loss_module(buffer.sample())
            loss = losses["loss_critic"]
            if iteration >= args.critic_warmup:
                loss = loss + losses["loss_objective"] + losses["loss_entropy"]
            optim.zero_grad()
            loss.backward()
            nn.utils.clip_grad_norm_(loss_module.parameters(), 1.0)
            optim.step()
        collector.update_policy_weights_()

        done = data["next", "done"].squeeze(-1)  # (worlds, events): episodes that ended in this batch
        row = {
            "iteration": iteration,
            "frames": (iteration + 1) * frames_per_batch,
            "minutes": (time.perf_counter() - start) / 60,
            "episodes": int(done.sum()),
            "episode_reward": data["next", EPISODE_REWARD][data["next", K.DONE]].mean().item(),
            "success_rate": data["next", "terminated"].squeeze(-1)[done].float().mean().item(),
            "decisions": len(samples),
            **{k: losses[k].item() for k in ("loss_objective", "loss_critic", "loss_entropy")},
        }
        history.append(row)
        print(
            f"iter {iteration:4d}  {row['minutes']:5.1f} min  episodes {row['episodes']:4d}  "
            f"reward/robot {row['episode_reward']:7.2f}  success {row['success_rate']:.2f}  "
            f"loss π {row['loss_objective']:+.3f} V {row['loss_critic']:.3f} H {row['loss_entropy']:+.4f}",
            flush=True,
        )
        finished = _spent(args, row["minutes"], iteration + 1) >= 1
        if out is not None and (finished or (iteration + 1) % args.save_every == 0):
            _save(out, args, cfg, history, actor, critic, optim)
        if finished:
            break
    collector.shutdown()
    if out is not None and args.eval_episodes:
        evaluate_saved(out, args.task, args.algo, args.eval_episodes, args.eval_seed)
    return history


def _start(args: argparse.Namespace, cfg, out: Path | None, actor, critic, optim):
    """The weights (new, ``--init-from``'s actor, or the resumed run's) and the run's first iteration,
    minutes spent and metrics rows."""
    if args.resume:
        first, spent_minutes, history = _restore(out, actor, critic, None if args.from_weights else optim)
        if args.from_weights:  # the sampling RNG was not saved with the weights: drawn like the worlds'
            torch.manual_seed(_world_seed(args.seed, first))
        if _spent(args, spent_minutes, first) >= 1:
            raise SystemExit(f"--resume: {out} has spent its budget (iteration {first}): nothing to continue")
        return first, spent_minutes, history
    if args.init_from:
        try:  # the saved policy's shape check and one-line errors
            start_from = load_policy(args.init_from, cfg).module
        except (ValueError, OSError) as err:
            raise SystemExit(f"--init-from: {err}") from None
        actor.load_state_dict(start_from.state_dict())
    return 0, 0.0, []


def _world_seed(seed: int, first: int) -> int:
    """The worlds' seed: the run's own, or for a run resumed at iteration ``first`` one drawn from both
    (new episodes, not the maps played before the interruption)."""
    return seed if first == 0 else int(np.random.SeedSequence([seed, first]).generate_state(1)[0])


def _save(out: Path, args: argparse.Namespace, cfg, history: list[dict], actor, critic, optim) -> None:
    """The metrics, the policy files (weights only) and the resumable state, each written atomically."""
    last = history[-1]
    atomic_write_csv(out / "metrics.csv", history)
    info = {"algo": args.algo, "task": args.task, "iteration": last["iteration"], "minutes": last["minutes"],
            "seed": args.seed}  # fmt: skip
    save_policy(actor, cfg, out, info, args.pool)
    state = {"actor": actor.state_dict(), "critic": critic.state_dict(), "optim": optim.state_dict(),
             "iteration": last["iteration"] + 1, "minutes": last["minutes"],
             "torch_rng": torch.get_rng_state()}  # fmt: skip
    atomic_torch_save(state, out / STATE)
    half = {name: {k: v.half() if v.is_floating_point() else v for k, v in state[name].items()}
            for name in ("actor", "critic")}  # fmt: skip
    atomic_torch_save({**half, "iteration": state["iteration"], "minutes": state["minutes"]}, out / WEIGHTS)


def _number(text: str) -> int | float:
    """A metrics.csv value as it was logged: counts as int, the rest as float."""
    return int(text) if text.lstrip("-").isdigit() else float(text)


def _restore(out: Path, actor, critic, optim) -> tuple[int, float, list[dict[str, float]]]:
    """Load the run's last save into the modules (``optim`` None: from the weights-only snapshot, the
    optimiser left new); its first iteration, minutes spent and metrics rows."""
    path = out / (WEIGHTS if optim is None else STATE)
    try:
        state = torch.load(path, weights_only=True)
    except Exception as err:  # truncated or foreign: whatever torch.load raises, as one line
        raise SystemExit(f"--resume: {path} is not readable ({type(err).__name__}: {err})") from None
    for module, name in ((actor, "actor"), (critic, "critic")):
        ours = module.state_dict()  # the snapshot's half-precision tensors back in the module's dtypes
        module.load_state_dict({k: v.to(ours[k].dtype) for k, v in state[name].items()})
    if optim is not None:
        optim.load_state_dict(state["optim"])
        torch.set_rng_state(state["torch_rng"])
    with (out / "metrics.csv").open(newline="") as f:
        history = [{k: _number(v) for k, v in row.items()} for row in csv.DictReader(f)]
    # metrics.csv is written just before state.pt: a crash between the two leaves rows the state lacks
    history = history[: state["iteration"]]
    source = "" if optim is not None else f" from {WEIGHTS} with a new optimiser"
    print(f"resuming {out} at iteration {state['iteration']} ({state['minutes']:.1f} min spent){source}",
          flush=True)  # fmt: skip
    return state["iteration"], state["minutes"], history


def evaluate_saved(out: Path, task: str, algo: str, episodes: int, seed: int) -> dict[str, float]:
    """The saved policy on the task's protocol (full communication) through its ``py:`` factory, beside
    Nearest and random-uniform on the same maps; results in OUT/eval/."""
    from catmip_rl.evaluation.evaluate import EvalSetting, evaluate

    if task not in ("task1", "task2", "task3"):
        return {}
    setting = EvalSetting(task)
    rates = {}
    for method in (f"{algo}=py:{out / 'policy.py'}:make_policy", "nearest", "random-uniform"):
        result = evaluate(method, setting, episodes=episodes, seed=seed)
        result.write(out / "eval" / result.method)
        rates[result.method] = result.summary["success_by_100"]
    print(
        "rescued by tick 100 on the protocol's maps: " + ", ".join(f"{k} {v:.2f}" for k, v in rates.items())
    )
    return rates


if __name__ == "__main__":
    main()
