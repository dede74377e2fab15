"""The methods an evaluation can play, by name: planners, window planners, AMAT models, your own policy.

    parse_method("rrt")                               # a planner (cell goals)
    parse_method("window:nearest")                    # a planner projected into the goal window
    parse_method("amat:task1")                        # a shipped model, labelled amat_task1
    parse_method("mine=py:/path/to/mine.py:make_policy")  # your policy (user_policy)
    parse_method("sync:nearest")                      # any method in the synchronous world
    parse_method("news-instant")                      # a reference row (catmip_env.planners.reference)

A model trained in the synchronous world (Synch-AMAT, ``amat:sync``) plays in it: every robot decides
together every ``max_ma_ticks`` ticks, the system it is.

:func:`make_policy` builds the policy a :class:`Method` names for one evaluation setting.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, replace
from difflib import get_close_matches
from pathlib import Path
from typing import TYPE_CHECKING, Any

from catmip_env.config import EnvConfig
from catmip_env.planners.baselines import PLANNERS, make_planner
from catmip_env.planners.reference import REFERENCES, make_reference
from catmip_env.planners.window import WINDOW_KINDS, make_window_planner
from catmip_rl.evaluation.checked_policy import make_user_policy
from catmip_rl.evaluation.user_policy import load_factory, parse_policy_source
from catmip_rl.store.shipped import file_sha256, model_file, resolve_model

if TYPE_CHECKING:  # AMAT's methods import torch when one is played: the planners run without it
    from catmip_rl.amat.model import AMAT

__all__ = [
    "Method",
    "parse_method",
    "parse_runs",
    "make_policy",
    "amat_label",
    "method_source",
    "policy_files",
    "changed_files",
    "own_modules",
    "METHOD_HELP",
    "PLAY_OPTIONS",
    "POLICY_SEED",
    "USER_KINDS",
]

PLAY_OPTIONS = (("loop_guard", "loop guard"), ("clean_occupancy", "clean occupancy"))
USER_KINDS = ("py", "policy")  # a user's policy: a py: factory's, or an object given to evaluate()
POLICY_SEED = 0
"""The seed a user's policy factory (and its ``sampled(seed)``) is given on every map set: a seed for its
own random stream that says nothing of the maps (per-world streams key on ``engine.world.keys``)."""
"""An AMAT's play options (the :class:`Method` fields a result's summary records) and their words."""

_PLANNER_NOTES = {
    "random-rescue": "random window goals with the planners' rescue rule",
    "random-uniform": "uniformly random valid window goals, no rescue rule: a learner's floor",
}
METHOD_HELP = " | ".join(f"{p} ({_PLANNER_NOTES[p]})" if p in _PLANNER_NOTES else p for p in PLANNERS) + (
    " | window:PLANNER (its goals projected into the 7x7 window) | window-noheading:PLANNER (projected "
    "along a heading-free path) | amat:PATH (a model file, checkpoint or run dir; one trained in the "
    "synchronous world plays in it) | amat:NAME (a shipped model) | amat-guard:PATH (argmax with the loop "
    "guard) | amat-clean:PATH (a cell-goal model reading occupancy from its action mask) | "
    "sync:METHOD (the method in the synchronous world: every robot decides together) | "
    "py:FILE.py:FACTORY or py:package.module:FACTORY (your policy: docs/benchmark-your-algorithm.md); "
    "NAME=METHOD names it on tables and plots | reference rows (they read the true world; the board's "
    "headroom, never ranked): " + ", ".join(f"{k} ({v[2]})" for k, v in REFERENCES.items())
)


@dataclass(frozen=True)
class Method:
    """``name`` as written on tables and plots; ``kind`` "planner", "window" (a planner projected into
    the goal window), "window-noheading" (the same along a heading-free path), "amat", "py" (a factory
    in a file or module), "policy" (an object given to ``evaluate(policy=...)``) or "reference" (a
    reference row, :mod:`catmip_env.planners.reference`); ``target`` the planner's or reference's name,
    the AMAT checkpoint path or the ``py:`` spec; ``loop_guard`` (AMAT) executes argmax with the loop
    guard of :class:`AmatExecutor`; ``synchronous``: plays in the synchronous world (every
    robot decides together every ``max_ma_ticks`` ticks), a ``sync:`` spec or a model trained in it;
    ``clean_occupancy`` (cell-goal AMAT): its active robots read occupancy from their action masks
    (:func:`~catmip_rl.amat.inputs.clean_occupancy`), an ``amat-clean:`` spec or a file that asks;
    ``isolated``: a ``py:`` policy plays in a worker process that holds no engine
    (:mod:`~catmip_rl.evaluation.sandbox`: the same results for an honest policy), always unless
    ``isolated=False`` asks for this process (tests, a debugger); False for every other kind (the
    project's planners and models, and an object, play in this process)."""

    name: str
    kind: str
    target: str
    loop_guard: bool = False
    synchronous: bool = False
    clean_occupancy: bool = False
    isolated: bool = True

    def __post_init__(self) -> None:
        object.__setattr__(self, "isolated", bool(self.isolated) and self.kind == "py")


def amat_label(path: str | Path) -> str:
    """A model's name on tables: its file's stem (``amat_task1``), or its run's folder for a training
    checkpoint (``runs/p/checkpoints/latest.pt`` -> ``p``, ``iter_200.pt`` -> ``p@iter_200``) or run dir."""
    path = Path(path)
    if path.is_dir():
        return path.resolve().name
    if path.parent.name == "checkpoints":
        run = path.parent.parent.resolve().name
        return run if path.stem == "latest" else f"{run}@{path.stem}"
    return path.stem


def parse_method(spec: str) -> Method:
    """A :class:`Method` from its spec (see :data:`METHOD_HELP`); ValueError naming a bad one. A
    ``py:`` file must exist; it is imported only when the policy is made."""
    spec = spec.strip()
    name = None
    if "=" in spec:
        name, spec = (s.strip() for s in spec.split("=", 1))
        if not name:
            raise ValueError(f"method {spec!r} has an empty name: write NAME={spec} or just {spec}")
    if spec.startswith("sync:"):
        inner = parse_method(spec[len("sync:") :])
        return replace(inner, name=name or f"sync:{inner.name}", synchronous=True)
    if spec.startswith("py:"):
        src = parse_policy_source(spec)
        default = Path(src.source).stem if src.is_file else src.source.rsplit(".", 1)[-1]
        return Method(name or default, "py", str(src))
    prefixes = (("amat:", False, False), ("amat-guard:", True, False), ("amat-clean:", False, True))
    for prefix, guard, clean in prefixes:
        if spec.startswith(prefix):
            path = spec[len(prefix) :]
            if not path:
                raise ValueError(f"amat method needs a checkpoint: {prefix}PATH")
            from catmip_rl.store.checkpoint import model_play

            target = resolve_model(path)
            label = amat_label(target) + ("-guard" if guard else "") + ("-clean" if clean else "")
            play = model_play(target)  # the file's own way to play, and what the spec adds
            return Method(
                name or label,
                "amat",
                str(target),
                guard or play.loop_guard,
                play.synchronous,
                clean or play.clean_occupancy,
            )
    for kind in WINDOW_KINDS:
        if spec.startswith(kind + ":"):
            planner = spec[len(kind) + 1 :]
            if planner not in PLANNERS:
                hint = _did_you_mean(spec)
                raise ValueError(
                    f"unknown planner {planner!r} in {spec!r}{hint}; choose one of {sorted(PLANNERS)}"
                )
            return Method(name or spec, kind, planner)
    return _named(spec, name)


def _named(spec: str, name: str | None) -> Method:
    """The planner or reference row ``spec`` names (a plain word), else ValueError with a hint."""
    if spec in REFERENCES:  # project code that reads the world: the board's headroom, never ranked
        return Method(name or spec, "reference", spec)
    if spec not in PLANNERS:
        looks_like_policy = ".py:" in spec or "." in spec.split(":")[0] and ":" in spec
        hint = f" (your policy? write py:{spec})" if looks_like_policy else _did_you_mean(spec)
        choices = (
            f"a planner {sorted(PLANNERS)}, window:PLANNER, window-noheading:PLANNER, amat:PATH, "
            "amat-guard:PATH, amat-clean:PATH, sync:METHOD, py:FILE.py:FACTORY or a reference row "
            f"{sorted(REFERENCES)}"
        )
        raise ValueError(f"unknown method {spec!r}{hint}; choose {choices}")
    return Method(name or spec, "planner", spec)


def _did_you_mean(spec: str) -> str:
    """`` (did you mean X?)`` for a spec close to a planner or a method prefix, else ''."""
    prefix, colon, rest = spec.partition(":")
    if colon:  # a mistyped prefix or planner: window:nearset, amta:task1
        prefixes = [*WINDOW_KINDS, "amat", "amat-guard", "amat-clean", "sync", "py"]
        fixed = [f"{p}:{rest}" for p in get_close_matches(prefix, prefixes, n=1)]
        if prefix in WINDOW_KINDS:
            fixed = [f"{prefix}:{p}" for p in get_close_matches(rest, list(PLANNERS), n=1)]
    else:
        fixed = get_close_matches(spec, [*PLANNERS, *REFERENCES], n=1)
    return f" (did you mean {fixed[0]}?)" if fixed else ""


def method_source(method: Method) -> dict[str, str] | None:
    """The file a method plays from and its SHA-256 (``{"file", "sha256"}``): an AMAT model file (a run
    dir's latest checkpoint) or a ``py:`` policy file; None for a planner, a module or an object."""
    source = parse_policy_source(method.target) if method.kind == "py" else None
    if source is not None and source.is_file:
        path = Path(source.source).expanduser()
    elif method.kind == "amat":
        path = model_file(Path(method.target))
    else:
        return None
    return {"file": str(path), "sha256": file_sha256(path)}


def policy_files(policy: Any) -> list[dict[str, str]] | None:
    """The files a played policy's answers depend on (its ``files``, :class:`catmip_env.play.Policy`:
    e.g. a ``py:`` policy's weights), each ``{"file", "sha256"}``; None if it names none."""
    files = getattr(policy, "files", None)
    return [{"file": str(f), "sha256": file_sha256(f)} for f in files] if files else None


def own_modules(target: str) -> list[dict[str, str]]:
    """The modules a ``py:`` policy imported from its own folder, as :func:`policy_files` records them:
    the source files in this process's ``sys.modules`` that lie under the policy file's folder (or a
    module policy's top package's), less the policy file itself, the catmip packages and any installed
    package (``site-packages``). What an entry binds besides the policy file and its weights."""
    src = parse_policy_source(target)
    if src.is_file:
        folder, own = Path(src.source).resolve().parent, Path(src.source).resolve()
    else:
        top = sys.modules.get(src.source.split(".")[0])
        where = getattr(top, "__file__", None)
        if where is None:
            return []
        folder, own = (
            Path(where).resolve().parent,
            Path(str(getattr(sys.modules.get(src.source), "__file__", ""))),
        )
    skip = [Path(m.__file__).resolve().parent for m in (sys.modules["catmip_env"], sys.modules["catmip_rl"])]
    found = set()
    for module in list(sys.modules.values()):
        path = getattr(module, "__file__", None)
        if not path or not path.endswith(".py"):
            continue
        path = Path(path).resolve()
        inside = path.is_relative_to(folder) and not any(path.is_relative_to(s) for s in skip)
        if inside and path != own and not {"site-packages", "dist-packages"} & set(path.parts):
            found.add(path)
    return [{"file": str(p), "sha256": file_sha256(p)} for p in sorted(found)]


def changed_files(recorded: list[dict[str, str]] | None) -> list[str]:
    """The files of ``recorded`` (:func:`policy_files`) that are missing or hold other contents now."""
    return [
        r["file"]
        for r in recorded or []
        if not Path(r["file"]).is_file() or file_sha256(r["file"]) != r["sha256"]
    ]


def parse_runs(spec: str) -> list[Method]:
    """The runs of one method: ``NAME=SPEC,SPEC,...`` are several training runs (seeds) of the method
    NAME, each played on the same maps and summarised together; any other spec is one run
    (:func:`parse_method`). ValueError naming a bad spec, or runs without a name."""
    name, sep, rest = spec.partition("=")
    if "," not in (rest if sep else spec):
        return [parse_method(spec)]
    if not sep or not name.strip():
        raise ValueError(f"several runs need one name: write NAME={spec.partition('=')[2] or spec}")
    specs = [s.strip() for s in rest.split(",") if s.strip()]
    return [replace(parse_method(s), name=name.strip()) for s in specs]


def make_policy(
    method: Method, env_config: EnvConfig, seed: int, model: AMAT | None = None, policy: Any = None
) -> tuple[Any, str, int | None]:
    """(policy with ``act(engine)``, goal mode, what the policy needs of the env config or None: an AMAT's
    goal window and teammate memory, :meth:`AmatConfig.env_overrides`) for ``method`` in the setting whose
    config is ``env_config``. ``model`` overrides loading an AMAT checkpoint; ``policy``
    is the object of a "policy" method (what a ``py:`` factory returns: a policy at either level). An
    isolated ``py:`` policy (:attr:`Method.isolated`) holds a worker process: end it with
    :func:`~catmip_rl.evaluation.sandbox.close_policy` when done. A planner is seeded ``seed``; a
    user's policy (``py:``, an object) gets :data:`POLICY_SEED` whatever the maps: its factory learns
    nothing of which maps it plays."""
    if method.kind == "planner":
        return make_planner(method.target, seed=seed), "cell", None
    if method.kind == "reference":
        reference, needs = make_reference(method.target, seed=seed)
        return reference, "cell", needs
    if method.kind in WINDOW_KINDS:
        teacher = make_window_planner(method.target, seed=seed, follow_heading=WINDOW_KINDS[method.kind])
        return teacher, "window", None
    if method.kind in USER_KINDS:  # told nothing of the maps: a seed for its own stream only
        seed = POLICY_SEED
    if method.kind == "py" and method.isolated:  # in a worker process that holds no engine
        from catmip_rl.evaluation.sandbox import isolated_policy

        wrapped = isolated_policy(method.target, method.name, env_config, seed)
        return wrapped, wrapped.goal_mode, None
    if method.kind in ("py", "policy"):
        if method.kind == "py":
            factory = load_factory(parse_policy_source(method.target), method.name)
        else:  # the object itself, checked as a factory's answer is
            factory = lambda _cfg, _seed: policy  # noqa: E731
        wrapped = make_user_policy(factory, env_config, seed, method.name)
        return wrapped, wrapped.goal_mode, None
    from catmip_rl.amat.onboard.execution import AmatExecutor, CellGoalExecutor
    from catmip_rl.store.checkpoint import load_model

    model = model if model is not None else load_model(method.target)
    needs = model.config.env_overrides()
    if model.config.goals == "cell":
        play = {"loop_guard": method.loop_guard, "clean_occupancy": method.clean_occupancy}
        return CellGoalExecutor(model, **play), "cell", needs or None
    if method.clean_occupancy:
        raise ValueError(
            f"{method.name}: clean occupancy reads a cell-goal mask over the whole map; {method.target} is a "
            "window model (its mask covers only its goal window)"
        )
    return AmatExecutor(model, loop_guard=method.loop_guard), "window", needs
