"""The headline numbers of the benchmark results and their targets: one :class:`Check` each, met or
not computed from the measured values (``run_all.py`` writes them into SUMMARY.md and run_all.json)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

__all__ = ["Check", "all_checks", "find_row", "row_value", "setting_label"]


@dataclass
class Check:
    """One headline number; ``target`` None = context only."""

    bench: str
    label: str
    value: float | None
    unit: str
    target: float | None = None
    op: str = ">="  # ">=", "<=" or "<"
    note: str = ""
    comparable: bool = True  # False: measured in a setting the target does not refer to

    @property
    def met(self) -> bool | None:
        if self.target is None or self.value is None or not self.comparable:
            return None
        return {
            ">=": self.value >= self.target,
            "<=": self.value <= self.target,
            "<": self.value < self.target,
        }[self.op]

    @property
    def status(self) -> str:
        if self.target is None:
            return ""
        if self.value is None:
            return "not measured"
        if not self.comparable:
            return "n/a"
        return "met" if self.met else "**unmet**"

    @property
    def ratio(self) -> float | None:
        """measured / target oriented so that >= 1 means met."""
        if self.met is None or not self.value or not self.target:
            return None
        return self.value / self.target if self.op == ">=" else self.target / self.value


def find_row(rows: list[dict], **want: Any) -> dict | None:
    for r in rows:
        if all(r.get(k) == v for k, v in want.items()):
            return r
    return None


def row_value(row: dict | None, key: str) -> float | None:
    return None if row is None or row.get(key) is None else float(row[key])


def setting_label(overrides: dict) -> str:
    if not overrides:
        return "full comm"
    return ", ".join(f"{k}={v}" for k, v in overrides.items())


def engine_checks(d: dict) -> list[Check]:
    rows = d.get("engine", [])
    out = []
    for preset, target in (("task2", 100_000), ("task3", 40_000)):
        r = find_row(rows, preset=preset, num_worlds=64, overrides={})
        out.append(Check("engine", f"{preset}, B = 64, full comm", row_value(r, "world_ticks_per_s"),
                         "world-ticks/s", target))  # fmt: skip
    for preset in ("task2", "task3"):
        r = next(
            (r for r in rows if r["preset"] == preset and r["num_worlds"] == 64 and r["overrides"]), None
        )
        if r is not None:
            label = f"{preset}, B = 64, {setting_label(r['overrides'])}"
            out.append(Check("engine", label, r["world_ticks_per_s"], "world-ticks/s"))
    pz = d.get("pettingzoo", [])
    worst = min(pz, key=lambda r: r["ticks_per_s"]) if pz else None
    label = "PettingZoo adapter, slowest setting"
    if worst:
        label += f" ({worst['preset']}, {setting_label(worst['overrides'])})"
    out.append(Check("engine", label, row_value(worst, "ticks_per_s"), "ticks/s", 5_000))
    if d.get("startup_s_cached") is not None:
        out.append(Check("engine", "fresh process start (numba cache warm)", d["startup_s_cached"], "s"))
    return out


def events_checks(d: dict) -> list[Check]:
    rows = d.get("engine", [])
    out = []
    for act in ([0, 0], [2, 5]):
        r = find_row(rows, preset="task2", num_worlds=64, activation=act)
        note = f"{r['events_per_s']:,.0f} decision events/s" if r else ""
        out.append(Check("events", f"event engine task2, B = 64, activation {tuple(act)}",
                         row_value(r, "world_ticks_per_s"), "world-ticks/s", 50_000, note=note))  # fmt: skip
    pz = d.get("pettingzoo", [])
    worst = min(pz, key=lambda r: r["events_per_s"]) if pz else None
    label = "PettingZoo macro adapter, slowest setting"
    if worst:
        label += f" ({worst['preset']}, activation {tuple(worst['activation'])})"
    note = f"{worst['world_ticks_per_s']:,.0f} world-ticks/s" if worst else ""
    worst_rate = row_value(worst, "events_per_s")
    out.append(Check("events", label, worst_rate, "decision events/s", 3_000, note=note))
    for r in d.get("planners", []):
        target = 20.0 if r["planner"] == "rrt" else 1.0
        out.append(Check("events", f"planner {r['planner']} ({r['preset']})", r["ms_per_decision"],
                         "ms/decision", target, "<"))  # fmt: skip
    return out


def amat_checks(d: dict, scaling: dict | None) -> list[Check]:
    lat = d.get("latency", [])
    out = []
    for n, s in ((2, 15), (3, 20), (6, 32)):
        r = find_row(lat, robots=n, map=s, active=n)
        out.append(Check("amat", f"batch-1 decision (torch), N = {n}, S = {s}, all active",
                         row_value(r, "decision_ms"), "ms"))  # fmt: skip
        target = 1.5 if n == 6 else None
        out.append(Check("amat", f"batch-1 decision (FastAmat), N = {n}, S = {s}, all active",
                         row_value(r, "fast_decision_ms"), "ms", target, "<="))  # fmt: skip
    if scaling:
        r = find_row(scaling.get("curves", {}).get("team_size", []), robots=6, map=32)
        if r is not None and r.get("fast_amat_ms") is not None:
            out.append(Check("amat", "FastAmat batch-1, N = 6, S = 32 (scaling run)", r["fast_amat_ms"],
                             "ms", 1.5, "<="))  # fmt: skip
    for r in d.get("acting", []):
        out.append(Check("amat", f"batched acting, B = {r['worlds']}", r["agent_decisions_per_s"],
                         "agent-decisions/s"))  # fmt: skip
    for r in d.get("training", []):
        best = r.get("best_agent_samples_per_s")
        parts = [f"median step; best {best:,.0f}/s"] if best else []
        parts.append(r.get("batch", "random maps"))
        if r.get("cpu_steal_pct") is not None:
            parts.append(f"CPU steal {r['cpu_steal_pct']:.0f} %")
        label = f"training step {r['precision']}, {r['worlds']}x{r['robots']} batch"
        if r.get("processes", 1) > 1:
            label += f", {r['processes']} processes x 1 thread"
        rate = r["agent_samples_per_s"]
        out.append(Check("amat", label, rate, "agent-samples/s", 5_000, note="; ".join(parts)))
    if not lat and not d.get("training"):
        out.append(Check("amat", "batch-1 decision, N = 6, S = 32, all active", None, "ms", 1.5, "<="))
    return out


def train_checks(d: dict) -> list[Check]:
    runs = d.get("runs", [])
    out = []
    precisions = sorted({r.get("precision", "fp32") for r in runs}, key=lambda p: (p != "fp32", p))
    for precision in precisions or ["fp32"]:
        mine = [r for r in runs if r.get("precision", "fp32") == precision]
        tag = "" if precision == "fp32" else f" [{precision}]"
        r10 = find_row(mine, epochs=10)
        r2 = find_row(mine, epochs=2)
        worlds = (r10 or r2 or {}).get("num_worlds", 64)
        paper = worlds == 64
        why = "" if paper else f"measured with {worlds} worlds, the target is for 64"
        if r10 is not None:
            out.append(Check("train", f"paper-recipe iteration (10 epochs){tag}", r10["iteration_s"], "s",
                             15.0, "<=", note=why, comparable=paper))  # fmt: skip
        elif r2 is not None:  # extrapolate: collection + advantages + 5x the 2-epoch update
            est = r2["collect_s"] + r2["advantage_s"] + 5 * r2["update_s"]
            note = "estimated from the 2-epoch run (update x 5)" + (f"; {why}" if why else "")
            out.append(Check("train", f"paper-recipe iteration (10 epochs){tag}, est.", est, "s", 15.0, "<=",
                             note=note, comparable=paper))  # fmt: skip
        else:
            out.append(Check("train", f"paper-recipe iteration (10 epochs){tag}", None, "s", 15.0, "<="))
        if precision == "fp32":
            first = r10 or r2
            collect_s = row_value(first, "collect_s")
            out.append(Check("train", "collection of 64 episodes", collect_s, "s", 2.0, "<=", note=why,
                             comparable=paper))  # fmt: skip
        ev = row_value(r2, "events_per_s")
        note = f"{r2['world_ticks_per_s']:,.0f} world-ticks/s" if r2 and "world_ticks_per_s" in r2 else ""
        if r2 is not None and ev is None:
            note = "this train.json predates the env-steps/s fields; re-run bench_train.py"
        if why:
            note = f"{note}; {why}" if note else why
        out.append(Check("train", f"env-steps/s end to end, 2 epochs{tag}", ev, "decision events/s", 1_000,
                         note=note, comparable=paper))  # fmt: skip
        for r in mine:  # other recipes: context only
            if r.get("epochs") not in (2, 10):
                note = f"collect {r['collect_s']:.1f} s, update {r['update_s']:.1f} s"
                label = f"iteration, {r['epochs']} epochs, {r.get('num_worlds', 64)} worlds{tag}"
                out.append(Check("train", label, r["iteration_s"], "s", note=note))
    return out


def executor_checks(d: dict) -> list[Check]:
    """AmatExecutor's default (FastAmat per neighbourhood) against its torch batch: the same actions
    (every one) and no slower (the ratio torch / FastAmat per event, >= 1)."""
    out = []
    for r in d.get("results", []):
        where = f"{r['setting']}, {r['worlds']} worlds"
        note = f"FastAmat {r['fast_ms']:.1f} ms vs torch {r['torch_ms']:.1f} ms per event"
        out.append(Check("executor", f"eval decisions, torch / FastAmat per event, {where}",
                         r["torch_over_fast"], "x", 1.0, note=note))  # fmt: skip
        out.append(Check("executor", f"eval decisions, same actions as torch, {where}",
                         r["same_actions"], "decisions", r["decisions"]))  # fmt: skip
    return out


def threads_checks(d: dict) -> list[Check]:
    """Both engines on several threads: never slower than one thread from 16 worlds; on 2 threads at least
    1.6x one thread at 64 worlds (event engine) and at 256 (primitive); always the same worlds."""
    out = []
    for r in d.get("rows", []):
        if r["threads"] == 1:
            continue
        engine = r.get("engine", "event")
        bar = (engine, r["worlds"]) in (("event", 64), ("primitive", 256)) and r["threads"] == 2
        target = 1.6 if bar else 1.0 if r["worlds"] >= 16 else None
        note = "same worlds as one thread" if r["same_worlds_as_one_thread"] else "**worlds differ**"
        if not r.get("split", True):  # the step stays on one thread: both timings run the same code
            target, note = None, f"{note}; below the split, one thread either way (the ratio is noise)"
        out.append(Check("threads", f"{engine} engine {r['task']}, B = {r['worlds']}, {r['threads']} threads",
                         r["speedup"], "x one thread", target, note=note))  # fmt: skip
        out.append(Check("threads", f"{r['task']}, {r['threads']} threads: same worlds as one thread",
                         float(r["same_worlds_as_one_thread"]), "", 1.0))  # fmt: skip
    return out


def peer_checks(d: dict) -> list[Check]:
    """The PettingZoo env at the primitive level: at least 1.5x POGEMA's env-steps/s on the same grid and
    team (not measured without POGEMA); the macro level's steps/s for the record."""
    out = []
    for r in d.get("ratios", []):
        where = f"{r['setting']} vs POGEMA {r['grid']}x{r['grid']}, {r['agents']} agents"
        rounds = ", ".join(f"{x:.2f}" for x in r.get("per_round", []))
        out.append(Check("peer", f"PettingZoo primitive env-steps/s, {where}", r["ratio"], "x POGEMA", 1.5,
                         note=f"rounds {rounds}" if rounds else "POGEMA not installed"))  # fmt: skip
    for r in d.get("rows", []):
        if r["env"] == "search_rescue_v0" and r["level"] == "macro":
            out.append(
                Check("peer", f"PettingZoo macro steps/s, {r['setting']}", r["steps_per_s"], "steps/s")
            )
    return out


def all_checks(results: dict[str, dict]) -> list[Check]:
    out: list[Check] = []
    if "engine" in results:
        out += engine_checks(results["engine"])
    if "events" in results:
        out += events_checks(results["events"])
    if "amat" in results:
        out += amat_checks(results["amat"], results.get("scaling"))
    if "train" in results:
        out += train_checks(results["train"])
    if "executor" in results:
        out += executor_checks(results["executor"])
    if "threads" in results:
        out += threads_checks(results["threads"])
    if "peer" in results:
        out += peer_checks(results["peer"])
    return out
