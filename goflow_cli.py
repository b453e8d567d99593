"""The `goflow` command: the gearbox assembly demo, policy and skill training, parameter
estimation and the sim-to-real diagnosis (`goflow --help`, `goflow COMMAND --help`).

Each command is a thin layer over a package function; its flags are built from the packages'
config dataclasses, which hold the defaults and the help. One spelling per concept: `--out FILE`
is the file a command makes, `--out-dir DIR` the folder it fills, `--runs DIR` the folder its run
folders go under, `--json FILE` an optional summary of what it printed, `--X-kwarg KEY=VALUE` an
option of what `--X` chose. A command that fails leaves no folder it created behind."""

from __future__ import annotations

import argparse
import ast
import dataclasses
import functools
import inspect
import io
import os
import shlex
import sys
import tempfile
import textwrap
import tokenize
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import Any

from goflow_common.config import key_values, parse_value
from goflow_common.errors import GoflowError, InputError, OutputPathError
from goflow_common.files import LOCK_NAME, check_output_file, write_atomic, write_json

__all__ = ["main", "make_parser"]

# ---------------------------------------------------------------------------------------------
# KEY=VALUE options (parsed by goflow_common.config.key_values)
# ---------------------------------------------------------------------------------------------


def _method_kwargs(
    pairs: Iterable[str] | None, methods: Iterable[str], flag: str = "--method-kwarg"
) -> dict[str, dict[str, Any]]:
    """--method-kwarg's [METHOD.]KEY=VALUE pairs -> {method: {key: value}}, the same format in
    every command: a bare KEY is an option of every method in `methods`, METHOD.KEY one of
    METHOD alone (InputError when METHOD is not among `methods`)."""
    methods = list(methods)
    out: dict[str, dict[str, Any]] = {m: {} for m in methods}
    for key, value in key_values(pairs, flag).items():
        method, dot, name = key.rpartition(".")
        if dot and method not in methods:
            raise InputError(
                f"{flag} {key}=...: {method!r} is not a method of this command; expected KEY=VALUE "
                f"or METHOD.KEY=VALUE with METHOD one of {methods}"
            )
        for m in [method] if dot else methods:
            if name in out[m]:
                raise InputError(f"{flag}: {m}'s option {name} is given twice")
            out[m][name] = value
    return {m: kwargs for m, kwargs in out.items() if kwargs}


def _one_method_kwargs(pairs: Iterable[str] | None, method: str) -> dict[str, Any]:
    """--method-kwarg of a command with one method: its {key: value}."""
    return _method_kwargs(pairs, [method]).get(method, {})


def _ppo_config(args: argparse.Namespace) -> Any:
    from goflow_common.config import config_with_overrides
    from learning.ppo import PPOConfig

    return config_with_overrides(PPOConfig, key_values(args.ppo, "--ppo"), owner="--ppo")


# ---------------------------------------------------------------------------------------------
# Flags from config dataclasses: the default is the field's, the help its comment
# ---------------------------------------------------------------------------------------------


class _HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Shows "(default: ...)" after the help of every flag that has a default."""

    def _get_help_string(self, action: argparse.Action) -> str:
        if action.default is None or action.default is False or not action.option_strings:
            return action.help or ""
        return super()._get_help_string(action)


@functools.lru_cache(maxsize=None)
def _field_docs(config_type: type) -> dict[str, str]:
    """Each field's comment in the class source: the one ending its line, else the comment lines
    right above it."""
    try:
        source = textwrap.dedent(inspect.getsource(config_type))
    except (OSError, TypeError):
        return {}
    comments = {
        tok.start[0]: tok.string.lstrip("#").strip()
        for tok in tokenize.generate_tokens(io.StringIO(source).readline)
        if tok.type == tokenize.COMMENT
    }
    lines = source.splitlines()
    docs = {}
    for node in ast.parse(source).body[0].body:
        if not (isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name)):
            continue
        text = comments.get(node.end_lineno)
        if text is None:
            above, line = [], node.lineno - 1
            while line in comments and lines[line - 1].lstrip().startswith("#"):
                above.insert(0, comments[line])
                line -= 1
            text = " ".join(above)
        if text:
            docs[node.target.id] = text
    return docs


def _field_default(config_type: type, name: str) -> Any:
    """The default of field `name` of `config_type` (its factory called)."""
    f = {f.name: f for f in dataclasses.fields(config_type)}[name]
    if f.default is not dataclasses.MISSING:
        return f.default
    return f.default_factory() if f.default_factory is not dataclasses.MISSING else None


def _add_field(
    parser: argparse.ArgumentParser,
    config_type: type,
    name: str,
    flag: str | None = None,
    doc: str | None = None,
    **kwargs: Any,
) -> None:
    """Add the flag (`flag`, default --<name>) of field `name` of `config_type`, stored as
    `args.<name>`: its default is the field's (unless required) and its help `doc`, else the
    field's comment; int, float, str and Path defaults give the value's type."""
    if not kwargs.get("required"):
        kwargs.setdefault("default", _field_default(config_type, name))
    default = kwargs.get("default")
    if (
        "type" not in kwargs
        and "action" not in kwargs
        and not isinstance(default, bool)
        and isinstance(default, (int, float, str, Path))
    ):
        kwargs["type"] = Path if isinstance(default, Path) else type(default)
    flag = flag or "--" + name.replace("_", "-")
    if "action" not in kwargs and "choices" not in kwargs:
        kwargs.setdefault("metavar", flag.lstrip("-").replace("-", "_").upper())
    help_text = doc or _field_docs(config_type).get(name) or ""
    parser.add_argument(flag, dest=name, help=help_text.replace("%", "%%"), **kwargs)


def _signature_default(function: Callable[..., Any], name: str) -> Any:
    """The default of parameter `name` of `function`."""
    return inspect.signature(function).parameters[name].default


class _Renamed(argparse.Action):
    """A flag's old spelling, kept for one release: it sets the new flag's value (appends, for a
    repeated flag) and says on stderr that the spelling changed. Hidden from --help."""

    def __init__(self, option_strings: list[str], dest: str, new: str, append: bool = False, **kwargs: Any) -> None:
        self.new, self.append = new, append
        super().__init__(option_strings, dest, help=argparse.SUPPRESS, **kwargs)

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: Any,
        option_string: str | None = None,
    ) -> None:
        print(
            f"goflow: note: {option_string} is now {self.new}; the old spelling goes in the next release",
            file=sys.stderr,
        )
        if self.append:
            values = [*(getattr(namespace, self.dest, None) or []), values]
        setattr(namespace, self.dest, values)


def _renamed(p: argparse.ArgumentParser, old: str, new: str, dest: str, append: bool = False, **kwargs: Any) -> None:
    """Keep `old` working as a deprecated spelling of flag `new` (stored as `args.<dest>`)."""
    p.add_argument(old, dest=dest, action=_Renamed, new=new, append=append, **kwargs)


def _require(p: argparse.ArgumentParser, dest: str, flag: str) -> None:
    """Flag `flag` is required, though not to argparse since an old spelling may give it
    (`_renamed`): `main` checks it after parsing."""
    p.set_defaults(required_flags=[*(p.get_default("required_flags") or []), (dest, flag)])


# ---------------------------------------------------------------------------------------------
# A failed command leaves nothing behind
# ---------------------------------------------------------------------------------------------

#: the args of the flags that name outputs (files or folders), in every command
_OUTPUTS = ("out", "out_dir", "runs", "results", "json", "record", "plot", "rows")


def _first_missing(path: Path) -> Path | None:
    """The outermost of `path` and its parents that does not exist (what writing `path` creates)."""
    return next((p for p in [*reversed(path.parents), path] if not p.exists()), None)


def _remove_unused(top: Path) -> None:
    """Remove the folders under `top` (itself included) that hold nothing, or only a run folder's
    lock, deepest first; files with content are kept."""
    if not top.is_dir():
        return
    for folder, _, _ in os.walk(top, topdown=False):
        with suppress(OSError):
            entries = os.listdir(folder)
            if set(entries) <= {LOCK_NAME}:
                for entry in entries:
                    os.remove(os.path.join(folder, entry))
                os.rmdir(folder)


@contextmanager
def _nothing_left_on_failure(paths: Iterable[Path | None]) -> Iterator[None]:
    """When the block fails (an error or Ctrl-C), the folders it created for `paths` and left
    unused are removed again: a refused or failed command leaves no empty folder or stale lock.
    What the block wrote (a checkpoint, a summary) stays."""
    created = {_first_missing(Path(p)) for p in paths if p is not None} - {None}
    try:
        yield
    except BaseException:
        for top in created:
            _remove_unused(top)
        raise


# ---------------------------------------------------------------------------------------------
# Work that may be interrupted, checks before it
# ---------------------------------------------------------------------------------------------


class _Interrupted(Exception):
    """Ctrl-C during resumable work; the message says what was kept and how to go on."""


@contextmanager
def _resumable(kept: Callable[[], str]) -> Iterator[None]:
    """Ctrl-C inside the block becomes one line: `kept()` (asked then) and how to resume."""
    try:
        yield
    except KeyboardInterrupt:
        raise _Interrupted(f"interrupted; {kept()}; run the same command to resume") from None


def _checkpoint_kept(run: Path) -> str:
    checkpoint = run / "checkpoint.pt"
    if checkpoint.is_file():
        return f"{checkpoint} keeps the last finished round"
    return f"no round had finished, so {run} holds no checkpoint yet"


def _round_note(config: Any, command: str) -> Any:
    """Check the environment of `config` (a TrainConfig), so that a bad id or option is the only
    message, and say so on stderr when `config.total_steps` is not whole rounds: a run trains
    whole rounds only. Returns the probed environment."""
    from learning.experiment import probe_env

    probe = probe_env(config.env, config.env_kwargs)
    per_round = config.steps_per_round()
    if config.total_steps % per_round:
        trained = max(1, config.total_steps // per_round) * per_round
        print(
            f"{command}: note: --steps {config.total_steps} is not a whole number of rounds (a round is "
            f"--iterations-per-round x num_envs x num_steps = {config.iterations_per_round} x "
            f"{config.ppo.num_envs} x {config.ppo.num_steps} = {per_round} steps); a run trains {trained} steps",
            file=sys.stderr,
            flush=True,
        )
    return probe


def _ray_flag(p: argparse.ArgumentParser) -> None:
    """--ray, the same on every command that runs a grid (learning.execution)."""
    from learning.execution import add_ray_flag

    add_ray_flag(p)


def _backend(args: argparse.Namespace, workers: int, inline: bool = False) -> Any:
    """The grid backend of --ray and `workers` (checked now; nothing starts until it is entered)."""
    from learning.execution import make_backend

    return make_backend(args.ray, workers, inline=inline)


# ---------------------------------------------------------------------------------------------
# demo
# ---------------------------------------------------------------------------------------------


def _demo_flags(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--scripted",
        action="store_true",
        help="the scripted pick-and-insert from the gears' true poses (no perception, no planner)",
    )
    p.add_argument(
        "--seed",
        type=int,
        default=None,
        help="the gears' random placement of the planned assembly (default: 0); the scripted run has none",
    )
    p.add_argument(
        "--decision",
        choices=["threshold", "cost"],
        default=None,
        help="how the planner decides: threshold (insert when Eq. 7 clears eta, the default) or cost "
        "(the plan of least expected time plus failure cost); the scripted run has no planner",
    )
    p.add_argument(
        "--cameras",
        choices=["realsense", "ideal"],
        default=None,
        help="the station's cameras: realsense (the default: a D415 scene and a D405 wrist camera with their "
        "depth noise, depth unit, scale error and calibration error) or ideal (perfect images and calibration); "
        "the scripted run has no cameras",
    )
    p.add_argument("--meshcat", action="store_true", help="show it live in Meshcat (localhost)")
    p.add_argument("--record", metavar="FILE.html", type=Path, help="save a Meshcat recording")
    p.add_argument("--json", metavar="PATH", type=Path, help="write the summary as JSON")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _cmd_demo(args: argparse.Namespace) -> int:
    record = check_output_file(args.record, "--record") if args.record else None
    json_path = check_output_file(args.json, "--json") if args.json else None
    if args.scripted and args.seed is not None:
        raise InputError(
            f"--seed {args.seed} with --scripted: the scripted run starts from the gears' nominal "
            "poses and draws nothing; drop --seed, or --scripted for the planned assembly"
        )
    if args.scripted and args.decision is not None:
        raise InputError(
            f"--decision {args.decision} with --scripted: the scripted run has no planner; drop one of them"
        )
    if args.scripted and args.cameras is not None:
        raise InputError(
            f"--cameras {args.cameras} with --scripted: the scripted run looks at nothing; drop one of them"
        )
    seed = 0 if args.seed is None else args.seed
    if seed < 0:
        raise InputError(f"--seed {seed}; expected a seed >= 0")
    from assembly.station import make_meshcat

    meshcat = None
    if args.meshcat or record:
        meshcat = make_meshcat()
        print(f"Meshcat: {meshcat.web_url()}", flush=True)
    with tempfile.TemporaryDirectory(prefix="goflow-demo-") as tmp:
        # The recording goes to a scratch file first: the summary and its JSON are out before it
        # is moved into place, so a recording that cannot be saved loses nothing else.
        scratch = Path(tmp) / "recording.html" if record else None
        if args.scripted:
            from assembly.demo import AssemblyConfig, format_summary, run_assembly

            summary = run_assembly(
                AssemblyConfig(),
                meshcat=meshcat,
                record=scratch,
                realtime=args.meshcat and not record,
                progress=not args.quiet,
            )
            print(format_summary(summary))
        else:
            from planning.assembly import PlannedAssemblyConfig, format_planned, run_planned_assembly
            from planning.domain import PlannerConfig

            config = PlannedAssemblyConfig(
                seed=seed,
                planner=PlannerConfig(decision=args.decision or "threshold"),
                cameras=args.cameras or PlannedAssemblyConfig.cameras,
            )
            summary = run_planned_assembly(config, meshcat=meshcat, record=scratch, progress=not args.quiet)
            print(format_planned(summary))
        if json_path:
            write_json(json_path, summary)
        if record:
            try:
                write_atomic(record, scratch.read_bytes())
            except OSError as exc:
                kept = f"the summary was printed{f' and written to {json_path}' if json_path else ''}"
                raise OutputPathError(
                    f"--record {record}: the recording was not saved ({exc.strerror or exc}); {kept}"
                ) from None
            print(f"recording: {record}")
    if args.meshcat and not record and sys.stdin.isatty():
        input("Press Enter to close Meshcat...")
    failed = "sim_error" in summary or (not args.scripted and summary.get("status") != "done")
    return 1 if failed else 0


# ---------------------------------------------------------------------------------------------
# train, experiment, sweep
# ---------------------------------------------------------------------------------------------


def _env_flags(p: argparse.ArgumentParser, config_type: type) -> None:
    _add_field(p, config_type, "env", required=True, doc="environment id, e.g. goflow/Toy2D-v0")
    p.add_argument("--env-kwarg", action="append", metavar="KEY=VALUE", help="an environment option")


def _budget_flags(p: argparse.ArgumentParser, config_type: type) -> None:
    _add_field(
        p,
        config_type,
        "total_steps",
        "--steps",
        doc="training environment steps per run, in whole rounds of --iterations-per-round x num_envs x "
        "num_steps steps (the default: 97 rounds of 2 x 8 x 128)",
    )
    _add_field(p, config_type, "iterations_per_round", doc="PPO iterations between validations")
    _add_field(p, config_type, "eval_episodes", doc="validation episodes per round, xi uniform on the box")
    p.add_argument("--ppo", action="append", metavar="KEY=VALUE", help="a PPOConfig field, e.g. num_steps=240")


_SIGNAL_HELP = (
    "what the sampler learns: the episode return, or success (1 if the return reaches the env's "
    "success threshold, else 0); adr and doraemon always learn returns"
)
_METHOD_KWARG_HELP = (
    "a sampler option, KEY=VALUE for every method or METHOD.KEY=VALUE for one, e.g. alpha=0.1 or goflow.alpha=0.1"
)


def _sampler_file_flag(p: argparse.ArgumentParser, what: str) -> None:
    """--sampler-file, the same in every command that draws xi from a distribution."""
    p.add_argument(
        "--sampler-file",
        type=Path,
        metavar="PATH",
        help=f"an estimate file written by `goflow estimate` (NFPDE, DROPO, BayesSim): {what}",
    )


def _train_flags(p: argparse.ArgumentParser) -> None:
    from learning.experiment import VECTORIZATIONS, TrainConfig
    from learning.samplers.registry import METHODS, SAMPLER_SIGNALS

    _env_flags(p, TrainConfig)
    _add_field(
        p,
        TrainConfig,
        "method",
        choices=METHODS,
        default=None,
        doc="the domain-randomization method (or --sampler-file)",
    )
    p.add_argument("--method-kwarg", action="append", metavar="KEY=VALUE", help=_METHOD_KWARG_HELP)
    _sampler_file_flag(p, "train on xi drawn from it, fixed (instead of --method)")
    _add_field(p, TrainConfig, "seed", doc="seed of the run")
    _budget_flags(p, TrainConfig)
    _add_field(
        p,
        TrainConfig,
        "sampler_batch",
        choices=["validation", "training"],
        doc="the episodes the sampler learns from: the uniform validation batch or its own training "
        "episodes (default: training for adr, validation for the rest)",
    )
    _add_field(p, TrainConfig, "sampler_signal", choices=SAMPLER_SIGNALS, doc=_SIGNAL_HELP)
    _add_field(
        p,
        TrainConfig,
        "vectorization",
        choices=VECTORIZATIONS,
        doc="batched: the envs as copies in one Drake plant (ids that have it, docs/envs.md); "
        "sync: one simulator per env",
    )
    p.add_argument(
        "--out-dir",
        type=Path,
        metavar="DIR",
        help="run folder (log.json, checkpoint.pt); a run resumes from its checkpoint "
        "(default: runs/<env>/<method>/seed<seed>)",
    )
    _renamed(p, "--out", "--out-dir", "out_dir", type=Path)


def _train_sampler(args: argparse.Namespace) -> tuple[str, dict[str, Any], Any]:
    """train's --method and --method-kwarg, or --sampler-file: (method, sampler options, the
    estimated sampler or None)."""
    if (args.method is None) == (args.sampler_file is None):
        raise InputError(
            "expected one of --method METHOD (a domain-randomization method) or --sampler-file PATH "
            "(an estimate of `goflow estimate`)"
        )
    if args.method is not None:
        return args.method, _one_method_kwargs(args.method_kwarg, args.method), None
    if args.method_kwarg:
        raise InputError(f"--method-kwarg {args.method_kwarg[0]} with --sampler-file: an estimate has no options")
    from learning.estimation.estimate_file import load_estimate

    sampler, _ = load_estimate(args.sampler_file)
    return "estimated", {"distribution": sampler.dist.to_dict()}, sampler


def _cmd_train(args: argparse.Namespace) -> int:
    from learning.experiment import ExperimentConfig, TrainConfig, train

    method, sampler_kwargs, estimate = _train_sampler(args)
    runs = _field_default(ExperimentConfig, "out")
    out = args.out_dir or runs / args.env.replace("/", "_") / method / f"seed{args.seed}"
    config = TrainConfig(
        env=args.env,
        env_kwargs=key_values(args.env_kwarg, "--env-kwarg"),
        method=method,
        sampler_kwargs=sampler_kwargs,
        seed=args.seed,
        total_steps=args.total_steps,
        iterations_per_round=args.iterations_per_round,
        eval_episodes=args.eval_episodes,
        ppo=_ppo_config(args),
        out=out,
        sampler_batch=args.sampler_batch,
        sampler_signal=args.sampler_signal,
        vectorization=args.vectorization,
    )
    probe = _round_note(config, "goflow train")
    if estimate is not None:
        from learning.estimation.estimate_file import check_estimate_space

        check_estimate_space(estimate, args.sampler_file, probe.space, args.env)
    with _nothing_left_on_failure([out]), _resumable(lambda: _checkpoint_kept(out)):
        log = train(config)
    step, success, ret = log["curve"][-1]
    print(
        f"{config.method} seed {config.seed}: success {success:.3f} on the uniform box, mean return "
        f"{ret:.2f} after {step} steps; log {out / 'log.json'}, checkpoint {out / 'checkpoint.pt'}"
    )
    return 0


def _experiment_flags(p: argparse.ArgumentParser) -> None:
    """The flags experiment and sweep share: env, budget, seeds, processes, folders."""
    from learning.experiment import ExperimentConfig
    from learning.samplers.registry import SAMPLER_SIGNALS

    _env_flags(p, ExperimentConfig)
    _budget_flags(p, ExperimentConfig)
    _add_field(p, ExperimentConfig, "sampler_signal", choices=SAMPLER_SIGNALS, doc=_SIGNAL_HELP)
    _add_field(p, ExperimentConfig, "seeds", doc="seeds per method (first-seed, first-seed + 1, ...)")
    _add_field(p, ExperimentConfig, "first_seed", doc="the first seed (earlier ones ran elsewhere)")
    _add_field(p, ExperimentConfig, "workers", doc="parallel processes")
    _ray_flag(p)
    _add_field(
        p,
        ExperimentConfig,
        "out",
        "--runs",
        metavar="DIR",
        doc="the folder of the run folders, <runs>/<name>/<method>/seed<k> (resumable)",
    )
    _renamed(p, "--out", "--runs", "out", type=Path)
    _add_field(p, ExperimentConfig, "results", metavar="DIR", doc="the folder of the results (<name>.json, figures)")
    _add_field(p, ExperimentConfig, "name", doc="the results' name (default: from the env and the methods)")


def _experiment_config(
    args: argparse.Namespace, methods: Iterable[str], sampler_kwargs: dict[str, dict[str, Any]] | None = None
) -> Any:
    from learning.experiment import ExperimentConfig

    return ExperimentConfig(
        env=args.env,
        env_kwargs=key_values(args.env_kwarg, "--env-kwarg"),
        methods=tuple(methods),
        seeds=args.seeds,
        first_seed=args.first_seed,
        total_steps=args.total_steps,
        iterations_per_round=args.iterations_per_round,
        eval_episodes=args.eval_episodes,
        ppo=_ppo_config(args),
        sampler_kwargs=sampler_kwargs or {},
        workers=args.workers,
        ray=args.ray,
        sampler_signal=args.sampler_signal,
        out=args.out,
        results=args.results,
        name=args.name,
    )


def _experiment_cmd_flags(p: argparse.ArgumentParser) -> None:
    from learning.experiment import ExperimentConfig
    from learning.samplers.registry import METHODS

    _add_field(
        p,
        ExperimentConfig,
        "methods",
        "--methods",
        nargs="+",
        type=str,
        choices=METHODS,
        default=list(_field_default(ExperimentConfig, "methods")),
        doc="the domain-randomization methods",
    )
    p.add_argument("--method-kwarg", action="append", metavar="KEY=VALUE", help=_METHOD_KWARG_HELP)
    _experiment_flags(p)


def _cmd_experiment(args: argparse.Namespace) -> int:
    from learning.experiment import format_summary, run_experiment

    config = _experiment_config(args, args.methods, _method_kwargs(args.method_kwarg, args.methods))
    _round_note(config.runs()[0], "goflow experiment")
    with _resumable(lambda: f"the runs under {config.out / config.stem()} keep their last finished rounds"):
        summary = run_experiment(config, command=args.provenance)
    print(format_summary(summary))
    print(f"results: {config.results / config.stem()}.json")
    for figure in summary.get("figures", []):
        print(f"figure: {figure}")
    return 0


def _sweep_flags(p: argparse.ArgumentParser) -> None:
    from learning.samplers.registry import METHODS
    from learning.sweep import SweepConfig

    _add_field(p, SweepConfig, "method", required=True, choices=METHODS)
    _add_field(p, SweepConfig, "param", required=True, doc="the sampler option swept, e.g. alpha")
    _add_field(p, SweepConfig, "values", nargs="+", required=True, type=str, doc="its values (JSON or strings)")
    p.add_argument(
        "--method-kwarg",
        action="append",
        metavar="KEY=VALUE",
        help="another option of the method, the same for every value",
    )
    _experiment_flags(p)


def _cmd_sweep(args: argparse.Namespace) -> int:
    from learning.sweep import SweepConfig, format_sweep, run_sweep

    config = SweepConfig(
        method=args.method,
        param=args.param,
        values=tuple(parse_value(v, "--values") for v in args.values),
        method_kwargs=_one_method_kwargs(args.method_kwarg, args.method),
        experiment=_experiment_config(args, [args.method]),
    )
    _round_note(config.experiment.runs()[0], "goflow sweep")
    with _resumable(lambda: f"the runs under {config.experiment.out} keep their last finished rounds"):
        sweep = run_sweep(config, command=args.provenance)
    print(format_sweep(sweep))
    print(f"results: {config.experiment.results / config.stem()}.json")
    for figure in sweep["figures"]:
        print(f"figure: {figure}")
    return 0


# ---------------------------------------------------------------------------------------------
# skill, evaluate
# ---------------------------------------------------------------------------------------------


def _skill_gear_flags(p: argparse.ArgumentParser, several: bool = False) -> None:
    from assembly.gearset import GEARS
    from learning.skill_file import SKILLS

    p.add_argument("--skill", default=SKILLS[0], choices=SKILLS, help="the skill")
    p.add_argument(
        "--gear",
        required=True,
        choices=sorted(GEARS),
        nargs="+" if several else None,
        help="the gear it handles" + (" (one or more, one job each)" if several else ""),
    )


def _refit_flags(p: argparse.ArgumentParser) -> None:
    """The flow refit's settings (skill train's stage 4, skill refit)."""
    from assembly.envs.gear_insertion import VARIANTS
    from learning.feasible_grid import FlowRefitConfig

    _add_field(
        p,
        FlowRefitConfig,
        "rounds",
        "--refit-rounds",
        doc="refit: flow updates from its own draws after the one from the measured grid",
    )
    _add_field(p, FlowRefitConfig, "episodes", "--refit-episodes", doc="refit: episodes per update")
    _add_field(p, FlowRefitConfig, "delta", doc="refit: the flow's mass allowed outside the feasible set")
    _add_field(p, FlowRefitConfig, "classifier_steps", doc="refit: Adam steps of the success classifier per update")
    p.add_argument(
        "--confirm-variant",
        choices=VARIANTS,
        default=None,
        help="refit: run every cell and draw that succeeded again in this env variant; it stays "
        "feasible only if it succeeds there too (default: the skill's own variant alone)",
    )


def _skill_runs_flag(p: argparse.ArgumentParser, what: str) -> None:
    from learning.skill_training import RUNS_SKILL_DIR

    p.add_argument("--runs", type=Path, default=RUNS_SKILL_DIR, metavar="DIR", help=what)


def _skill_out_flag(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--out",
        type=Path,
        metavar="FILE",
        help="the skill file to write (default: <runs>/<skill>-<gear>.pt; the shipped files only when named)",
    )


def _skill_flags(p: argparse.ArgumentParser) -> None:
    from learning.skill_training import SkillRecipe

    sub = p.add_subparsers(dest="action", required=True, metavar="ACTION")

    def action(name: str, summary: str) -> argparse.ArgumentParser:
        return sub.add_parser(name, help=summary, description=summary, formatter_class=_HelpFormatter)

    t = action("train", "train a skill with its recipe (GoFlow, refinement, flow fit, refit), then export it")
    _skill_gear_flags(t, several=True)
    _add_field(t, SkillRecipe, "seed", doc="seed of the training run")
    _add_field(
        t,
        SkillRecipe,
        "sensing",
        choices=["pose", "wrench"],
        doc="what the policy observes: tool poses (pose) or also the estimated external wrench (wrench)",
    )
    _add_field(t, SkillRecipe, "total_steps", "--steps", doc="stage 1 (GoFlow) training environment steps")
    _add_field(t, SkillRecipe, "refine_steps", doc="stage 2 (refinement) training environment steps; 0: none")
    _add_field(t, SkillRecipe, "fit_rounds", doc="stage 3 (flow fit, policy frozen) rounds; 0: none")
    _refit_flags(t)
    _skill_runs_flag(t, "the folder of the training runs <runs>/<skill>-<gear>/ (resumable)")
    _skill_out_flag(t)
    t.add_argument("--workers", type=int, default=1, help="gears trained at once, one process each")
    _ray_flag(t)

    e = action("export", "package a `goflow train` run folder as a skill file")
    _skill_gear_flags(e)
    e.add_argument("--run", type=Path, required=True, metavar="DIR", help="the `goflow train` run folder")
    _skill_runs_flag(e, "the folder of the default --out")
    _skill_out_flag(e)

    r = action("refit", "refit a skill file's flow to where its policy succeeds (stage 4 of train)")
    _skill_gear_flags(r)
    r.add_argument("--path", type=Path, metavar="FILE", help="the skill file refitted (default: the shipped one)")
    r.add_argument(
        "--feasible-from",
        type=Path,
        default=None,
        metavar="FILE",
        help="a skill file with the same policy whose measured feasible set to use where --path "
        "holds none (only a confirming variant it lacks is run)",
    )
    _refit_flags(r)
    _skill_runs_flag(r, "the folder of the resumable measurement <runs>/<skill>-<gear>-refit/")
    _skill_out_flag(r)
    r.add_argument("--workers", type=int, default=1, help="processes running its episodes")
    _ray_flag(r)

    s = action("show", "a skill file's provenance and its flow against its measured feasible set")
    _skill_gear_flags(s)
    s.add_argument("--path", type=Path, metavar="FILE", help="a skill file other than the shipped one")


def _cmd_skill(args: argparse.Namespace) -> int:
    actions = {"train": _skill_train, "export": _skill_export, "refit": _skill_refit, "show": _skill_show}
    return actions[args.action](args)


def _skill_show(args: argparse.Namespace) -> int:
    from learning.skill_evaluation import describe
    from learning.skill_file import load_skill

    print(describe(load_skill(args.skill, args.gear, path=args.path)))
    return 0


def _skill_export(args: argparse.Namespace) -> int:
    from learning.skill_file import skill_path
    from learning.skill_training import export_skill

    out = args.out or skill_path(args.skill, args.gear, args.runs)
    skill = export_skill(args.run, args.skill, args.gear, out, command=args.provenance)
    print(f"{skill!r} -> {out}")
    return 0


def _skill_refit(args: argparse.Namespace) -> int:
    from learning.skill_feasible_set import refit_skill
    from learning.skill_file import skill_path
    from learning.skill_training import skill_run_folder

    out = args.out or skill_path(args.skill, args.gear, args.runs)
    folder = Path(f"{skill_run_folder(args.skill, args.gear, args.runs)}-refit")
    grid, refit = _grid_config(args), _refit_config(args)
    backend = _backend(args, args.workers, inline=True)
    with _resumable(lambda: f"{folder} keeps the measurement's finished jobs and the last update"):
        skill = refit_skill(
            args.path or skill_path(args.skill, args.gear),
            out,
            grid,
            refit=refit,
            folder=folder,
            backend=backend,
            command=args.provenance,
            progress=True,
            feasible_from=args.feasible_from,
        )
    print(f"{skill!r} -> {out}")
    return 0


def _refit_config(args: argparse.Namespace) -> Any:
    from learning.feasible_grid import FlowRefitConfig

    return FlowRefitConfig(
        rounds=args.rounds, episodes=args.episodes, delta=args.delta, classifier_steps=args.classifier_steps
    )


def _grid_config(args: argparse.Namespace) -> Any:
    from learning.skill_feasible_set import INSERT_GRID

    return dataclasses.replace(INSERT_GRID, confirm_variant=args.confirm_variant)


def _skill_recipe(args: argparse.Namespace, gears: list[str]) -> Any:
    """The recipe of skill train's flags, its stages checked before anything is written."""
    from learning.skill_training import SkillRecipe

    recipe = SkillRecipe(
        seed=args.seed,
        sensing=args.sensing,
        total_steps=args.total_steps,
        refine_steps=args.refine_steps,
        fit_rounds=args.fit_rounds,
        grid=_grid_config(args),
        refit=_refit_config(args),
    )
    if args.refine_steps < 0 or args.fit_rounds < 0:
        bad = "--refine-steps" if args.refine_steps < 0 else "--fit-rounds"
        raise InputError(f"{bad} {getattr(args, bad[2:].replace('-', '_'))}; expected an integer >= 0")
    for gear in gears:
        recipe.stages(args.skill, gear, Path("unused"))  # TrainConfig checks each stage's settings
    return recipe


def _skill_train(args: argparse.Namespace) -> int:
    """skill train: one gear in this process, or several (or on --ray / --workers) one job each."""
    from learning.skill_file import skill_path
    from learning.skill_training import skill_run_folder, train_skill, train_skills

    gears = list(dict.fromkeys(args.gear))
    recipe = _skill_recipe(args, gears)
    if len(gears) > 1 or args.ray or args.workers != 1:
        backend = _backend(args, args.workers)
        with _resumable(lambda: f"the training runs under {args.runs} keep their last finished rounds"):
            skills = train_skills(
                args.skill, gears, recipe, runs=args.runs, out=args.out, command=args.provenance, backend=backend
            )
    else:
        with _resumable(lambda: _checkpoint_kept(skill_run_folder(args.skill, gears[0], args.runs))):
            skills = [train_skill(args.skill, gears[0], recipe, runs=args.runs, out=args.out, command=args.provenance)]
    for gear, skill in zip(gears, skills):
        print(f"{skill!r} -> {args.out or skill_path(args.skill, gear, args.runs)}")
    return 0


def _evaluate_flags(p: argparse.ArgumentParser) -> None:
    from assembly.gearset import GEARS
    from learning.skill_evaluation import evaluate_skill, evaluate_skill_jobs, xi_source
    from learning.skill_file import SKILLS

    p.add_argument("--skill", default=SKILLS[0], choices=SKILLS, help="the skill")
    p.add_argument("--gear", required=True, choices=sorted(GEARS), help="the gear it handles")
    default = functools.partial(_signature_default, evaluate_skill)
    p.add_argument("--variant", default=default("variant"), choices=["fast", "panda"], help="the env's variant")
    p.add_argument(
        "--xi-from",
        default=None,
        type=xi_source,
        metavar="{uniform,flow,radius:R}",
        help=f"where the episodes' grasp errors are drawn from: the skill's flow, uniform over the box, or "
        f"radius:R, uniform over the disk of radius R metres around the skill's centre with the yaw uniform "
        f"over the box (a capture range; default: {default('xi')}; or --sampler-file)",
    )
    _renamed(p, "--xi", "--xi-from", "xi_from", type=xi_source)
    _sampler_file_flag(p, "the grasp errors are drawn from it (instead of --xi-from)")
    p.add_argument("--episodes", type=int, default=default("episodes"), help="episodes to run")
    p.add_argument("--seed", type=int, default=default("seed"), help="seed of the episodes")
    p.add_argument("--path", type=Path, metavar="FILE", help="a skill file other than the shipped one")
    p.add_argument("--json", metavar="PATH", type=Path, help="write the result as JSON")
    default = functools.partial(_signature_default, evaluate_skill_jobs)
    p.add_argument(
        "--jobs",
        type=int,
        default=default("jobs"),
        help="split the episodes into this many jobs, each seeded from (seed, job): the result "
        "depends on --jobs, not on --workers or --ray",
    )
    p.add_argument("--workers", type=int, default=1, help="jobs run at once, one process each")
    _ray_flag(p)


def _sampler_file_or(flag: str, value: Any, path: Path | None) -> None:
    """`flag` (the other source of xi) and --sampler-file are exclusive: InputError when both are given."""
    if value is not None and path is not None:
        raise InputError(
            f"{flag} {value} and --sampler-file {path}: expected one source of xi, not both "
            f"({flag} or an estimate of `goflow estimate`)"
        )


def _estimate_for(path: Path, space: Any, env: str) -> tuple[Any, dict[str, Any]]:
    """--sampler-file's estimate, its ParamSpace checked against `env`'s `space`: (the sampler,
    what a result records of it: `estimate_source`)."""
    from learning.estimation.estimate_file import estimate_source, load_estimate_for

    sampler, doc = load_estimate_for(path, space, env)
    return sampler, estimate_source(path, sampler, doc)


def _cmd_evaluate(args: argparse.Namespace) -> int:
    from learning.execution import InlineBackend

    _sampler_file_or("--xi-from", args.xi_from, args.sampler_file)
    backend = _backend(args, args.workers, inline=True)
    with backend:  # a Ray cluster that cannot be reached fails here, before --json's folder is made
        json_path = check_output_file(args.json, "--json") if args.json else None
        from learning.skill_evaluation import evaluate_skill, evaluate_skill_jobs
        from learning.skill_file import load_skill, skill_path

        skill = load_skill(args.skill, args.gear, path=args.path)
        sampler, source = None, None
        xi = args.xi_from or _signature_default(evaluate_skill, "xi")
        if args.sampler_file is not None:
            sampler, source = _estimate_for(args.sampler_file, skill.space, skill.env_id)
            xi = "estimate"
        if args.jobs == 1 and isinstance(backend, InlineBackend):
            result = evaluate_skill(
                skill,
                variant=args.variant,
                xi=xi,
                episodes=args.episodes,
                seed=args.seed,
                progress=True,
                sampler=sampler,
            )
        else:
            result = evaluate_skill_jobs(
                args.path or skill_path(args.skill, args.gear),
                variant=args.variant,
                xi=xi,
                episodes=args.episodes,
                seed=args.seed,
                jobs=args.jobs,
                backend=backend,
                progress=True,
                sampler=sampler,
            )
    print(
        f"{args.skill} {args.gear} ({args.variant}, xi from {args.sampler_file or xi}): success "
        f"{result.success_rate:.3f} +- {result.success_se:.3f} over {result.episodes} episodes, mean return "
        f"{result.mean_return:.2f} ({result.seconds:.0f} s)"
    )
    if json_path:
        write_json(json_path, {**result.to_json(), **({"sampler_file": source} if source else {})})
    return 0


# ---------------------------------------------------------------------------------------------
# bench, collect, estimate
# ---------------------------------------------------------------------------------------------


def _bench_flags(p: argparse.ArgumentParser) -> None:
    from perception.speed import BenchConfig

    p.add_argument(
        "target",
        choices=["perception", "calibration"],
        help="perception: seconds per posterior; calibration: coverage of the "
        "posteriors' credible regions on fresh scenes, both views, every "
        "perturbation group",
    )
    p.add_argument("--json", metavar="PATH", type=Path, help="write the result as JSON")
    _add_field(p, BenchConfig, "posteriors", doc="perception: close-view posteriors timed per gear")
    # calibration's options default to CalibrationConfig's (not imported here: parsing any
    # command must not load the scene renderer)
    p.add_argument(
        "--seed",
        type=int,
        default=None,
        metavar="SEED",
        help="seed of the random poses (perception: 0) or scenes (calibration: held out from tuning by default)",
    )
    p.add_argument(
        "--scenes",
        type=int,
        default=None,
        metavar="SCENES",
        help="calibration: scenes per perturbation group (three gears each)",
    )
    p.add_argument(
        "--groups", nargs="+", metavar="GROUP", default=None, help="calibration: perturbation groups (default: all)"
    )
    p.add_argument("--workers", type=int, default=None, metavar="WORKERS", help="calibration: processes (default 1)")
    p.add_argument("--plot", metavar="PATH", type=Path, help="calibration: write the reliability plot (PNG)")
    p.add_argument(
        "--rows",
        metavar="PATH",
        type=Path,
        help="calibration: also write every posterior's row (gzip'd JSON, 1-2 MB a set), which --pool reads",
    )
    p.add_argument(
        "--pool",
        nargs="+",
        metavar="RESULT",
        type=Path,
        default=None,
        help="calibration: judge these results (their --rows files) pooled, running nothing; "
        "--json then writes the pooled summary and the files' names",
    )


def _cmd_bench(args: argparse.Namespace) -> int:
    if args.target == "calibration":
        return _bench_calibration(args)
    from perception.speed import BenchConfig, bench_perception

    if args.posteriors < 1:
        raise InputError(f"--posteriors {args.posteriors}: expected at least 1")
    json_path = check_output_file(args.json, "--json") if args.json else None
    seed = 0 if args.seed is None else args.seed
    result = bench_perception(BenchConfig(posteriors=args.posteriors, seed=seed))
    print(
        f"perception: {result['seconds_per_posterior']:.3f} s per close-view posterior, "
        f"{result['hypotheses_per_second']:.0f} hypotheses/s ({result['renderer']}); "
        f"{result['seconds_per_scene']:.3f} s per scene image (detection + a far posterior "
        "per gear)"
    )
    if json_path:
        write_json(json_path, result)
    return 0


def _bench_calibration(args: argparse.Namespace) -> int:
    from perception.calibration import (
        CalibrationConfig,
        markdown_table,
        reliability_plot,
        run_calibration,
        save_result,
    )
    from perception.scenes import PERTURBATIONS

    overrides = {k: getattr(args, k) for k in ("scenes", "workers", "seed") if getattr(args, k) is not None}
    if args.pool:
        return _pool_calibration(args, overrides)
    if args.groups:
        unknown = [g for g in args.groups if g not in PERTURBATIONS]
        if unknown:
            raise InputError(f"--groups {' '.join(unknown)}: unknown; expected some of {', '.join(PERTURBATIONS)}")
        overrides["groups"] = tuple(args.groups)
    config = CalibrationConfig(**overrides)
    json_path = check_output_file(args.json, "--json") if args.json else None
    plot_path = check_output_file(args.plot, "--plot") if args.plot else None
    rows_path = check_output_file(args.rows, "--rows") if args.rows else None
    result = run_calibration(config, progress=True)
    print(markdown_table(result["summary"]))
    if json_path or rows_path:
        save_result(json_path, result, rows_path)
    if plot_path:
        reliability_plot(result, plot_path)
    return 0


def _pool_calibration(args: argparse.Namespace, overrides: dict[str, Any]) -> int:
    """`goflow bench calibration --pool`: stored results judged together."""
    from perception.calibration import load_result, markdown_table, pool_results, reliability_plot, sets_text

    given = [f"--{k}" for k in overrides] + (["--groups"] if args.groups else []) + (["--rows"] if args.rows else [])
    if given:
        raise InputError(f"{' '.join(given)} with --pool: pooling runs nothing; expected only --json and --plot")
    json_path = check_output_file(args.json, "--json") if args.json else None
    plot_path = check_output_file(args.plot, "--plot") if args.plot else None
    result = pool_results([load_result(path) for path in args.pool])
    print(markdown_table(result["summary"]))
    print(sets_text(result["sets"]))
    if json_path:
        # the rows stay in the pooled files: the JSON holds what was judged and from which files
        write_json(
            json_path,
            {
                "config": result["config"],
                "summary": result["summary"],
                "sets": result["sets"],
                "results": [str(p) for p in args.pool],
            },
        )
    if plot_path:
        reliability_plot(result, plot_path)
    return 0


def _collect_flags(p: argparse.ArgumentParser) -> None:
    from assembly.transition import TRANSITION_SIMS
    from learning.estimation.collect import NO_TRANSITIONS, CollectConfig
    from learning.estimation.targets import TARGETS

    _add_field(
        p,
        CollectConfig,
        "env",
        required=True,
        doc=f"an env id with a step-from-state simulator: {', '.join(TRANSITION_SIMS)} "
        f"(not {', '.join(NO_TRANSITIONS)}: see docs/nfpde.md)",
    )
    _add_field(
        p,
        CollectConfig,
        "xi",
        "--true-xi",
        choices=list(TARGETS),
        default=None,
        doc="the distribution of the true parameters, one draw per trajectory (mixture, mixture5: 3 or 5 "
        "Gaussians with means in an L shape; default: gaussian, or --sampler-file)",
    )
    _renamed(p, "--xi", "--true-xi", "xi", choices=list(TARGETS))
    _sampler_file_flag(p, "the true parameters are drawn from it (instead of --true-xi), e.g. to check an estimate")
    _add_field(p, CollectConfig, "episodes", doc="trajectories")
    _add_field(
        p,
        CollectConfig,
        "steps",
        type=int,
        doc="steps per trajectory (default: the env's episode length, e.g. 120 for goflow/Cartpole-v0)",
    )
    _add_field(p, CollectConfig, "policy")
    _add_field(p, CollectConfig, "seed", doc="seed of the true parameters, start states and actions")
    p.add_argument("--out", required=True, type=Path, metavar="FILE", help="dataset file (.npz)")


def _cmd_collect(args: argparse.Namespace) -> int:
    from learning.estimation.collect import CollectConfig, collect_to_file

    _sampler_file_or("--true-xi", args.xi, args.sampler_file)
    config = CollectConfig(
        env=args.env,
        xi=args.xi,
        sampler_file=args.sampler_file,
        episodes=args.episodes,
        steps=args.steps,
        policy=args.policy,
        seed=args.seed,
    )
    check_output_file(args.out, "--out")
    ds = collect_to_file(config, args.out, progress=True, command=args.provenance)
    print(
        f"{ds.num_episodes} trajectories, {ds.num_transitions} transitions of {ds.env_id} "
        f"(true xi {args.sampler_file or config.xi}, policy {config.policy}) -> {args.out}"
    )
    return 0


def _estimate_flags(p: argparse.ArgumentParser) -> None:
    from learning.estimation import ESTIMATORS
    from learning.estimation.estimate import EstimateConfig

    p.add_argument("--data", required=True, type=Path, metavar="FILE", help="dataset file written by `goflow collect`")
    _add_field(p, EstimateConfig, "method", required=True, choices=ESTIMATORS, doc="the estimator")
    p.add_argument(
        "--method-kwarg", action="append", metavar="KEY=VALUE", help="a field of the method's config, e.g. beta=1000"
    )
    p.add_argument(
        "--out",
        required=True,
        type=Path,
        metavar="FILE",
        help="estimate file (.json): the --sampler-file of train, evaluate and collect",
    )
    _add_field(p, EstimateConfig, "seed", doc="seed of the estimation")
    _add_field(p, EstimateConfig, "sim_budget")
    _add_field(p, EstimateConfig, "workers")


def _cmd_estimate(args: argparse.Namespace) -> int:
    from learning.estimation.estimate import EstimateConfig, estimate_file

    config = EstimateConfig(
        method=args.method,
        seed=args.seed,
        sim_budget=args.sim_budget,
        workers=args.workers,
        options=_one_method_kwargs(args.method_kwarg, args.method),
    )
    config.method_config()  # the method's options, checked before the work
    check_output_file(args.out, "--out")
    info = estimate_file(args.data, args.out, config, command=args.provenance, progress=True)
    print(f"{config.method}: {info['sim_calls']} simulator calls, {info['seconds']:.1f} s -> {args.out}")
    return 0


def _diagnose_flags(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--log",
        required=True,
        type=Path,
        help="robot log: .npz (project format), .csv (libfranka/franka_ros columns) or a folder in "
        "the Gaz et al. layout (rbt_log/exciting_traj_*.txt)",
    )
    p.add_argument(
        "--model",
        default="arm",
        choices=["arm", "station", "perception"],
        help="arm: torque and state channels of the arm; station: an insertion log (contact effects); "
        "perception: a perception log (camera effects)",
    )
    p.add_argument(
        "--out-dir", type=Path, metavar="DIR", help="report folder (report.md, report.json, figures); required"
    )
    _renamed(p, "--out", "--out-dir", "out_dir", type=Path)
    _require(p, "out_dir", "--out-dir")
    p.add_argument("--effects", nargs="+", metavar="NAME", help="catalogue effects to consider (default: all)")
    p.add_argument("--seed", type=int, default=0, help="seed of the bootstrap intervals")
    p.add_argument(
        "--torque-filter",
        default="matched",
        choices=["none", "matched"],
        help="arm: 'matched' smooths the logged torques with the kernel of the "
        "acceleration's derivative filter; 'none' compares raw torques (docs/sim2real.md)",
    )
    p.add_argument(
        "--torque-hold",
        default="zoh",
        choices=["zoh", "sample"],
        help="arm: 'zoh': a torque sample holds over the period after it (a 1 kHz torque "
        "loop's log); 'sample' a torque measured at its instant (logs sampled well below 1 kHz)",
    )
    p.add_argument(
        "--band",
        default="auto",
        metavar="HZ|auto|none",
        help="arm: the residual is judged below this edge [Hz]; 'auto' from the log's "
        "excitation; 'none' every sample against the broadband noise (docs/sim2real.md)",
    )
    p.add_argument(
        "--episodes",
        type=int,
        default=10,
        help="station: episodes per success rate of the shipped skill (0: skip the downstream figure)",
    )


def _band_option(value: str):
    """--band: 'auto', 'none' or an edge in Hz -> a BandConfig or None."""
    from sim2real.band import BandConfig

    if value == "auto":
        return BandConfig()
    if value == "none":
        return None
    try:
        hz = float(value)
    except ValueError:
        raise InputError(f"--band = {value!r}; expected 'auto', 'none' or an edge in Hz (e.g. 6)") from None
    return BandConfig(cutoff=hz)


def _cmd_diagnose(args: argparse.Namespace) -> int:
    from sim2real.diagnosis import DiagnosisConfig
    from sim2real.commands import diagnose_file
    from sim2real.replay import ReplayConfig

    config = DiagnosisConfig(
        effects=tuple(args.effects) if args.effects else None,
        seed=args.seed,
        replay=ReplayConfig(torque_filter=args.torque_filter, torque_hold=args.torque_hold),
        band=_band_option(args.band),
    )
    if args.episodes < 0:
        raise InputError(f"--episodes = {args.episodes}; expected an integer >= 0")
    d, paths = diagnose_file(args.log, args.out_dir, args.model, config, progress=True, episodes=args.episodes)
    v = d.verdict
    print(f"{v['label']}: {v['text']}")
    print(f"report -> {args.out_dir / 'report.md'}")
    return 0


def _sim2real_flags(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="action", required=True)
    summary = (
        "a log of a simulated reality (the arm, an insertion in the station, the scene camera) with injected effects"
    )
    m = sub.add_parser("make-log", help=summary, description=summary, formatter_class=_HelpFormatter)
    m.add_argument(
        "--model",
        default="arm",
        choices=["arm", "station", "perception"],
        help="arm: an exciting trajectory; station: one insertion episode of the shipped skill; "
        "perception: the scene camera's first look on random scenes",
    )
    m.add_argument(
        "--effect",
        action="append",
        metavar="NAME=VALUE",
        help="an effect and its value: NAME=VALUE sets its first parameter, NAME.PARAM=VALUE any; "
        "per-joint values are one number or 7 comma-separated (e.g. coulomb=0.8, "
        "payload.dm=0.5, torque_offset=0,0,0,0,0.5,0,0)",
    )
    m.add_argument(
        "--model-kwarg",
        action="append",
        metavar="KEY=VALUE",
        help="an option of the model: arm: duration, seed or another field of "
        "sim2real.reality.RealityConfig; station: gear, seed, xi or noise; perception: scenes or seed",
    )
    _renamed(m, "--set", "--model-kwarg", "model_kwarg", append=True)
    m.add_argument("--out", required=True, type=Path, metavar="FILE", help="log file (.npz, or .csv for the arm)")
    sub.add_parser(
        "effects",
        help="list the effect catalogue",
        description="list the effect catalogue",
        formatter_class=_HelpFormatter,
    )


def _cmd_sim2real(args: argparse.Namespace) -> int:
    if args.action == "effects":
        from sim2real.catalogue import CATALOGUE

        for e in CATALOGUE.values():
            params = ", ".join(
                f"{p.name} [{p.unit}] in [{p.low:g}, {p.high:g}]{' per joint' if p.per_joint else ''}" for p in e.params
            )
            print(f"{e.name} ({e.place}): {e.meaning}\n    {params}")
        return 0
    from sim2real.commands import make_log_file

    path = make_log_file(args.effect or [], args.out, key_values(args.model_kwarg, "--model-kwarg"), args.model)
    print(f"log -> {path}")
    return 0


# ---------------------------------------------------------------------------------------------
# The parser and main
# ---------------------------------------------------------------------------------------------

#: name: (summary, function adding its flags, function running it)
_Command = tuple[str, Callable[[argparse.ArgumentParser], None], Callable[[argparse.Namespace], int]]
COMMANDS: dict[str, _Command] = {
    "demo": ("run the gearbox assembly", _demo_flags, _cmd_demo),
    "train": ("train a policy with a DR sampler (GoFlow protocol)", _train_flags, _cmd_train),
    "experiment": (
        "compare methods over seeds: <results>/<name>.json and figures",
        _experiment_cmd_flags,
        _cmd_experiment,
    ),
    "sweep": ("sweep one option of one method: an experiment per value", _sweep_flags, _cmd_sweep),
    "skill": ("a skill file: train, export, refit or show", _skill_flags, _cmd_skill),
    "evaluate": ("success rate of a skill", _evaluate_flags, _cmd_evaluate),
    "bench": (
        "perception benchmarks (perception: speed of pose posteriors; calibration: their coverage)",
        _bench_flags,
        _cmd_bench,
    ),
    "collect": ("log (s, a, s') trajectories with known true parameters", _collect_flags, _cmd_collect),
    "estimate": ("estimate a parameter distribution from a dataset", _estimate_flags, _cmd_estimate),
    "diagnose": (
        "sim-to-real gap diagnosis of a robot log: where, which effect, how far",
        _diagnose_flags,
        _cmd_diagnose,
    ),
    "sim2real": (
        "the simulated reality: make-log (a log with injected effects), effects (the catalogue)",
        _sim2real_flags,
        _cmd_sim2real,
    ),
}


def _version() -> str:
    """The installed package's version."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("goflow")
    except PackageNotFoundError:
        return "unknown (not installed; pip install -e .)"


def make_parser(commands: Iterable[str] | None = None) -> argparse.ArgumentParser:
    """The `goflow` parser; only the flags of `commands` (default: all) are built, since building
    a command's flags imports its package."""
    wanted = set(COMMANDS if commands is None else commands)
    parser = argparse.ArgumentParser(prog="goflow", description=__doc__.split("\n\n")[0].replace("\n", " "))
    parser.add_argument("--version", action="version", version=f"goflow {_version()}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, (summary, add_flags, run) in COMMANDS.items():
        p = sub.add_parser(name, help=summary, description=summary, formatter_class=_HelpFormatter)
        p.set_defaults(func=run)
        if name in wanted:
            add_flags(p)
    return parser


def _expected(exc: BaseException) -> bool:
    """Whether `exc` is a failure the user can act on (bad input, a path, an unknown id) rather
    than a bug: those are reported in one line."""
    if isinstance(exc, (GoflowError, ValueError, TypeError, OSError)):
        return True
    gym_error = sys.modules.get("gymnasium.error")
    return gym_error is not None and isinstance(exc, gym_error.Error)


def main(argv: list[str] | None = None) -> int:
    """Run the command in `argv` (default: sys.argv[1:]); return the exit status.

    Flags map to fields of the packages' config dataclasses, which give their defaults and help.
    Output paths are checked before any work; a command that fails removes the folders it created
    and left unused. An expected failure (bad input, an unwritable path, an unknown id) is one
    line on stderr and status 2; Ctrl-C is one line saying what was kept and how to resume,
    status 130. Bad flags are argparse's usage message and status 2 (SystemExit)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    name = f"goflow {argv[0]}" if argv and argv[0] in COMMANDS else "goflow"
    try:
        args = make_parser([argv[0]] if argv else []).parse_args(argv)
        args.provenance = "goflow " + shlex.join(argv)
        if args.command in ("skill", "sim2real"):
            name = f"goflow {args.command} {args.action}"
        missing = [flag for dest, flag in getattr(args, "required_flags", ()) if getattr(args, dest) is None]
        if missing:
            raise InputError(f"{', '.join(missing)} is required")
        with _nothing_left_on_failure(getattr(args, dest, None) for dest in _OUTPUTS):
            return args.func(args)
    except _Interrupted as exc:
        print(f"{name}: {exc}", file=sys.stderr)
        return 130
    except KeyboardInterrupt:
        print(f"{name}: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:
        if not _expected(exc):
            raise
        print(f"{name}: {' '.join(str(exc).split()) or type(exc).__name__}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
