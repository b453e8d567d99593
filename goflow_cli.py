"""The `goflow` command: a thin dispatcher over the packages (nothing imports this module)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def _cmd_demo(args: argparse.Namespace) -> int:
    if not args.scripted:
        print("goflow demo: only the scripted assembly exists so far; run `goflow demo --scripted`",
              file=sys.stderr)
        return 2
    from assembly.demo import AssemblyConfig, format_summary, run_assembly
    from assembly.station import make_meshcat

    meshcat = None
    if args.meshcat or args.record:
        meshcat = make_meshcat()
        print(f"Meshcat: {meshcat.web_url()}", flush=True)
    summary = run_assembly(AssemblyConfig(), meshcat=meshcat,
                           record=Path(args.record) if args.record else None,
                           realtime=args.meshcat and not args.record, progress=not args.quiet)
    print(format_summary(summary))
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(summary, indent=2))
    if args.meshcat and not args.record:
        input("Press Enter to close Meshcat...") if sys.stdin.isatty() else None
    return 1 if "sim_error" in summary else 0


def _key_values(pairs: list[str] | None, flag: str) -> dict:
    """["a=1", "b=x"] -> {"a": 1, "b": "x"} (values parsed as JSON when they are JSON)."""
    out = {}
    for pair in pairs or []:
        if "=" not in pair:
            raise SystemExit(f"goflow: {flag} {pair!r}: expected KEY=VALUE")
        key, value = pair.split("=", 1)
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value
    return out


def _method_kwargs(pairs: list[str] | None, methods) -> dict:
    """["goflow.alpha=0.1"] -> {"goflow": {"alpha": 0.1}}: sampler options per method."""
    out: dict = {}
    for key, value in _key_values(pairs, "--method-kwarg").items():
        method, dot, name = key.partition(".")
        if not dot or method not in methods:
            raise SystemExit(f"goflow: --method-kwarg {key}=...: expected METHOD.KEY=VALUE with METHOD one of "
                             f"{list(methods)}")
        out.setdefault(method, {})[name] = value
    return out


def _ppo_config(args: argparse.Namespace):
    import dataclasses
    from learning.ppo import PPOConfig
    overrides = _key_values(args.ppo, "--ppo")
    known = {f.name for f in dataclasses.fields(PPOConfig)}
    unknown = sorted(set(overrides) - known)
    if unknown:
        raise SystemExit(f"goflow: unknown --ppo option(s) {unknown}; known: {sorted(known)}")
    return PPOConfig(**overrides)


def _cmd_train(args: argparse.Namespace) -> int:
    from learning.experiment import TrainConfig, train
    out = Path(args.out) if args.out else Path("runs") / args.env.replace("/", "_") / args.sampler / f"seed{args.seed}"
    config = TrainConfig(env=args.env, env_kwargs=_key_values(args.env_kwarg, "--env-kwarg"),
                         method=args.sampler, sampler_kwargs=_key_values(args.sampler_kwarg, "--sampler-kwarg"),
                         seed=args.seed, total_steps=args.steps,
                         iterations_per_round=args.iterations_per_round,
                         eval_episodes=args.eval_episodes, ppo=_ppo_config(args), out=out,
                         sampler_batch=args.sampler_batch)
    log = train(config)
    step, success, ret = log["curve"][-1]
    print(f"{args.sampler} seed {args.seed}: success {success:.3f} on the uniform box, mean return "
          f"{ret:.2f} after {step} steps; log {out / 'log.json'}, checkpoint {out / 'checkpoint.pt'}")
    return 0


def _experiment_config(args: argparse.Namespace, methods, sampler_kwargs=None, name=None, results=None):
    from learning.experiment import ExperimentConfig
    return ExperimentConfig(env=args.env, env_kwargs=_key_values(args.env_kwarg, "--env-kwarg"),
                            methods=tuple(methods), seeds=args.seeds, total_steps=args.steps,
                            iterations_per_round=args.iterations_per_round,
                            eval_episodes=args.eval_episodes, ppo=_ppo_config(args),
                            sampler_kwargs=sampler_kwargs or {}, workers=args.workers,
                            sampler_signal=getattr(args, "sampler_signal", "return"),
                            out=Path(args.out), results=Path(results or args.results), name=name or args.name)


def _cmd_experiment(args: argparse.Namespace) -> int:
    from learning.experiment import format_summary, run_experiment
    command = "goflow " + " ".join(sys.argv[1:])
    config = _experiment_config(args, args.methods, _method_kwargs(args.method_kwarg, args.methods))
    summary = run_experiment(config, command=command)
    print(format_summary(summary))
    if args.env.startswith("goflow/Toy2D"):
        from learning.plots import plot_toy2d_densities
        path = Path(args.results) / f"{config.stem()}-densities.png"
        plot_toy2d_densities(config, path)
        print(f"densities: {path}")
    return 0


def _cmd_sweep(args: argparse.Namespace) -> int:
    from learning.experiment import format_summary, run_experiment
    from learning.plots import plot_sweep
    command = "goflow " + " ".join(sys.argv[1:])
    stem = args.name or f"sweep-{args.env.split('/')[-1].lower()}-{args.method}-{args.param}"
    results = Path(args.results)
    rows = []
    for value in args.values:
        v = json.loads(value) if value[:1].isdigit() or value[:1] in "-[" else value
        # each value's experiment (its JSON and curves) goes to <results>/<stem>/
        summary = run_experiment(_experiment_config(
            args, [args.method], {args.method: {args.param: v}}, name=f"{stem}-{value}", results=results / stem), command=command)
        print(format_summary(summary))
        res = summary["methods"][args.method]
        rows.append({"value": v, "final_success_mean": res["final_success_mean"],
                     "final_success_se": res["final_success_se"], "seeds": res["seeds"]})
    results.mkdir(parents=True, exist_ok=True)
    sweep = {"env": args.env, "method": args.method, "param": args.param, "steps": args.steps, "rows": rows,
             "command": command}
    (results / f"{stem}.json").write_text(json.dumps(sweep, indent=2))
    plot_sweep(sweep, results / f"{stem}.png")
    best = max(rows, key=lambda r: r["final_success_mean"])
    print(f"best {args.param} = {best['value']} (success {best['final_success_mean']:.3f}); "
          f"{results / stem}.json and .png")
    return 0


def _cmd_skill(args: argparse.Namespace) -> int:
    from learning.skills import SkillRecipe, describe, export_skill, load_skill, skill_path, train_skill
    if args.action == "train":
        recipe = SkillRecipe(seed=args.seed, total_steps=args.steps, refine_steps=args.refine_steps,
                             fit_rounds=args.fit_rounds)
        skill = train_skill(args.skill, args.gear, recipe, runs=args.runs, out=args.out,
                            command="goflow " + " ".join(sys.argv[1:]))
        print(f"{skill!r} -> {args.out or skill_path(args.skill, args.gear)}")
    elif args.action == "export":
        if not args.run:
            raise SystemExit("goflow skill export: --run FOLDER (a `goflow train` run folder) is required")
        out = args.out or skill_path(args.skill, args.gear)
        skill = export_skill(args.run, args.skill, args.gear, out, command="goflow " + " ".join(sys.argv[1:]))
        print(f"{skill!r} -> {out}")
    else:
        print(describe(load_skill(args.skill, args.gear, path=args.out)))
    return 0


def _cmd_evaluate(args: argparse.Namespace) -> int:
    from learning.skills import evaluate_skill, load_skill
    skill = load_skill(args.skill, args.gear, path=args.path)
    result = evaluate_skill(skill, variant=args.variant, xi=args.xi, episodes=args.episodes, seed=args.seed)
    print(f"{args.skill} {args.gear} ({args.variant}, xi {args.xi}): success {result['success_rate']:.3f} "
          f"+- {result['success_se']:.3f} over {args.episodes} episodes, mean return {result['mean_return']:.2f} "
          f"({result['seconds']:.0f} s)")
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(result, indent=2))
    return 0


def _add_run_flags(p: argparse.ArgumentParser, steps: int) -> None:
    p.add_argument("--env", required=True, help="environment id, e.g. goflow/Toy2D-v0")
    p.add_argument("--env-kwarg", action="append", metavar="KEY=VALUE", help="environment option")
    p.add_argument("--steps", type=int, default=steps, help="training environment steps per run")
    p.add_argument("--iterations-per-round", type=int, default=2,
                   help="PPO iterations between validation + sampler update")
    p.add_argument("--eval-episodes", type=int, default=64, help="validation episodes per round")
    p.add_argument("--ppo", action="append", metavar="KEY=VALUE", help="PPOConfig field")


def _add_experiment_flags(p: argparse.ArgumentParser) -> None:
    p.add_argument("--seeds", type=int, default=5)
    p.add_argument("--workers", type=int, default=2, help="parallel processes")
    p.add_argument("--out", default="runs", help="folder for run checkpoints and logs")
    p.add_argument("--results", default="docs/results", help="folder for the result JSON and plot")
    p.add_argument("--name", help="result file stem (default from the env id)")


def _cmd_bench(args: argparse.Namespace) -> int:
    from perception.bench import BenchConfig, bench_perception
    if args.posteriors < 1:
        raise ValueError(f"--posteriors {args.posteriors}: expected at least 1")
    result = bench_perception(BenchConfig(posteriors=args.posteriors, seed=args.seed))
    print(f"perception: {result['seconds_per_posterior']:.3f} s per posterior, "
          f"{result['hypotheses_per_second']:.0f} hypotheses/s ({result['renderer']})")
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(result, indent=2))
    return 0


def _cmd_collect(args: argparse.Namespace) -> int:
    from learning.estimation.collect import CollectConfig, collect_to_file
    command = "goflow " + " ".join(sys.argv[1:])
    config = CollectConfig(env=args.env, xi=args.xi, episodes=args.episodes, steps=args.steps,
                           policy=args.policy, seed=args.seed)
    ds = collect_to_file(config, args.out, progress=True, command=command)
    print(f"{ds.num_episodes} trajectories, {ds.num_transitions} transitions of {ds.env_id} "
          f"(xi {args.xi}, policy {args.policy}) -> {args.out}")
    return 0


def _cmd_estimate(args: argparse.Namespace) -> int:
    from learning.estimation.estimate import EstimateConfig, estimate_file
    command = "goflow " + " ".join(sys.argv[1:])
    config = EstimateConfig(method=args.method, seed=args.seed, sim_budget=args.sim_budget,
                            workers=args.workers, options=_key_values(args.option, "--option"))
    info = estimate_file(args.data, args.out, config, command=command)
    print(f"{args.method}: {info['sim_calls']} simulator calls, {info['seconds']:.1f} s -> {args.out}")
    return 0


def make_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="goflow", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    demo = sub.add_parser("demo", help="run the gearbox assembly")
    demo.add_argument("--scripted", action="store_true",
                      help="scripted pick-and-insert of all three gears")
    demo.add_argument("--meshcat", action="store_true", help="show it live in Meshcat (localhost)")
    demo.add_argument("--record", metavar="FILE.html", help="save a Meshcat recording")
    demo.add_argument("--json", metavar="PATH", help="write the per-gear summary as JSON")
    demo.add_argument("--quiet", action="store_true", help="no progress bar")
    demo.set_defaults(func=_cmd_demo)

    from learning.methods import METHODS, SAMPLER_SIGNALS
    train = sub.add_parser("train", help="train a policy with a DR sampler (GoFlow protocol)")
    _add_run_flags(train, 200_000)
    train.add_argument("--sampler", required=True, choices=METHODS)
    train.add_argument("--sampler-kwarg", action="append", metavar="KEY=VALUE")
    train.add_argument("--seed", type=int, default=0)
    train.add_argument("--sampler-batch", choices=["validation", "training"],
                       help="episodes the sampler learns from (default: the method's own; "
                            "'training' makes GoFlow learn from its own draws)")
    train.add_argument("--out", help="run folder (resumes from its checkpoint)")
    train.set_defaults(func=_cmd_train)

    experiment = sub.add_parser("experiment", help="methods x seeds; writes docs/results/<env>.json")
    _add_run_flags(experiment, 200_000)
    experiment.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS)
    experiment.add_argument("--method-kwarg", action="append", metavar="METHOD.KEY=VALUE",
                            help="a sampler option of one method, e.g. goflow.alpha=0.1")
    experiment.add_argument("--sampler-signal", choices=SAMPLER_SIGNALS, default="return",
                            help="what GoFlow and LSDR learn from (ADR and DORAEMON always use returns)")
    _add_experiment_flags(experiment)
    experiment.set_defaults(func=_cmd_experiment)

    sweep = sub.add_parser("sweep", help="a hyperparameter sweep of one method (appendix A.2)")
    _add_run_flags(sweep, 200_000)
    sweep.add_argument("--method", required=True, choices=METHODS)
    sweep.add_argument("--param", required=True, help="sampler option to sweep, e.g. alpha")
    sweep.add_argument("--values", nargs="+", required=True)
    _add_experiment_flags(sweep)
    sweep.set_defaults(func=_cmd_sweep)

    from assembly.gearset import GEARS
    skill = sub.add_parser("skill", help="train, export or show a shipped skill (learning/skill_files/)")
    skill.add_argument("action", choices=["train", "export", "show"])
    skill.add_argument("--skill", default="insert", choices=["insert"])
    skill.add_argument("--gear", required=True, choices=sorted(GEARS))
    skill.add_argument("--seed", type=int, default=0)
    skill.add_argument("--steps", type=int, default=120_000, help="stage 1 (GoFlow) training environment steps")
    skill.add_argument("--refine-steps", type=int, default=48_000,
                       help="stage 2 steps, the flow learning from its own draws (0: none)")
    skill.add_argument("--fit-rounds", type=int, default=30,
                       help="stage 3 flow updates with the policy frozen (0: none)")
    skill.add_argument("--runs", default="runs/skills", help="folder for the training run (resumable)")
    skill.add_argument("--run", help="export: the `goflow train` run folder to package")
    skill.add_argument("--out", help="skill file (default: the shipped location)")
    skill.set_defaults(func=_cmd_skill)

    evaluate = sub.add_parser("evaluate", help="success rate of a shipped skill")
    evaluate.add_argument("--skill", default="insert", choices=["insert"])
    evaluate.add_argument("--gear", required=True, choices=sorted(GEARS))
    evaluate.add_argument("--variant", default="fast", choices=["fast", "panda"])
    evaluate.add_argument("--xi", default="flow", choices=["uniform", "flow"],
                          help="grasp errors from the skill's flow or uniform over the box")
    evaluate.add_argument("--episodes", type=int, default=100)
    evaluate.add_argument("--seed", type=int, default=0)
    evaluate.add_argument("--path", help="a skill file other than the shipped one")
    evaluate.add_argument("--json", metavar="PATH", help="write the result as JSON")
    evaluate.set_defaults(func=_cmd_evaluate)

    bench = sub.add_parser("bench", help="speed benchmarks (perception: pose posteriors per gear)")
    bench.add_argument("target", choices=["perception"])
    bench.add_argument("--json", metavar="PATH", help="write the result as JSON")
    bench.add_argument("--posteriors", type=int, default=2, help="close-view posteriors per gear")
    bench.add_argument("--seed", type=int, default=0)
    bench.set_defaults(func=_cmd_bench)

    collect = sub.add_parser("collect", help="log (s, a, s') trajectories with known true parameters")
    collect.add_argument("--env", required=True, help="simulator id, e.g. goflow/Cartpole-v0")
    collect.add_argument("--xi", required=True, choices=["gaussian", "mixture"],
                         help="true parameter distribution (mixture: means in an L shape)")
    collect.add_argument("--episodes", type=int, required=True)
    collect.add_argument("--steps", type=int, help="steps per trajectory (default: the env's episode)")
    collect.add_argument("--policy", default="random", help="'random' or a PPO checkpoint path")
    collect.add_argument("--seed", type=int, default=0)
    collect.add_argument("--out", required=True, help="dataset file (.npz)")
    collect.set_defaults(func=_cmd_collect)

    from learning.estimation import ESTIMATORS
    estimate = sub.add_parser("estimate", help="estimate a parameter distribution from a dataset")
    estimate.add_argument("--data", required=True, help="dataset file written by `goflow collect`")
    estimate.add_argument("--method", required=True, choices=ESTIMATORS)
    estimate.add_argument("--out", required=True, help="estimate file (.json), loadable as a Sampler")
    estimate.add_argument("--seed", type=int, default=0)
    estimate.add_argument("--sim-budget", type=int, default=100_000, help="simulator calls")
    estimate.add_argument("--workers", type=int, default=1, help="simulator processes")
    estimate.add_argument("--option", action="append", metavar="KEY=VALUE",
                          help="a field of the method's config, e.g. beta=1000")
    estimate.set_defaults(func=_cmd_estimate)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = make_parser().parse_args(argv)
    try:
        return args.func(args)
    except (FileNotFoundError, ValueError) as exc:  # bad input: one clear line, no traceback
        print(f"goflow {args.command}: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
