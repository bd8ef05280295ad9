"""The ``shadowlab`` command: run | sweep | methods | scenes | bench | figures.

Every user error (an invalid config or experiment config, a bad option, a scene that
cannot be built, work too large for the machine) prints ``shadowlab: error: <message>``
on stderr and exits with status 2; outputs are written atomically at the end of a
command, so a failed one leaves no file behind.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def _common_config_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", nargs="?", help="a TOML config (default: the built-in default)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a config key, e.g. --set camera.resolution=[256,256] "
                        "(repeatable)")


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="shadowlab", description=__doc__)
    ap.add_argument("--heap", choices=("retain", "system"), default=None,
                    help="'retain': keep memory freed between frames in the process (fewer "
                         "page faults for the next frame's arrays; a resident size near "
                         "the peak); 'system': glibc's defaults; default: $SHADOWLAB_HEAP, "
                         "else system")
    sub = ap.add_subparsers(dest="command", required=True)

    run = sub.add_parser("run", help="run methods on a scene and compare with the reference")
    _common_config_args(run)
    run.add_argument("--out", help="output folder (default: the config's output.dir)")
    run.add_argument("--quiet", action="store_true", help="no progress bar")

    sweep = sub.add_parser("sweep", help="a grid of configs x frames on a Dask cluster, "
                           "gathered into one results table")
    sweep.add_argument("config", help="a TOML run config with a [sweep] table")
    sweep.add_argument("--set", dest="overrides", action="append", default=[],
                       metavar="KEY=VALUE", help="override a key of every grid point")
    sweep.add_argument("--out", help="output folder (default: the config's output.dir)")
    sweep.add_argument("--workers", type=int, default=None,
                       help="worker processes of the local cluster (default: CPU count)")
    sweep.add_argument("--scheduler", metavar="ADDRESS",
                       help="use the existing Dask cluster at ADDRESS (tcp://host:8786)")
    sweep.add_argument("--repeats", type=int, default=3,
                       help="warm calls per method and task (median; default 3)")
    sweep.add_argument("--quiet", action="store_true", help="no progress bar")

    sub.add_parser("methods", help="list methods and their options")
    sub.add_parser("scenes", help="list procedural scenes and their parameters")

    bench = sub.add_parser("bench", help="time methods against the Embree reference")
    _common_config_args(bench)
    bench.add_argument("--size", choices=("ci", "full"), default="full",
                       help="built-in case sizes when no config is given (default: full)")
    bench.add_argument("--only", action="append", default=[], metavar="NAME",
                       help="only this built-in case (repeatable; see shadowlab/configs/bench.toml)")
    bench.add_argument("--repeats", type=int, default=5, help="warm runs per method (median)")
    bench.add_argument("--out", default=None,
                       help="JSON results (default: bench.json; with --cold, cold_start.json)")
    bench.add_argument("--cold", action="store_true",
                       help="cold start instead: each method of the config (default: the "
                            "built-in default run) in a fresh process with an empty JAX "
                            "compilation cache; import, setup, first call, compile and warm "
                            "times against the 20 s aim")
    bench.add_argument("--quiet", action="store_true")
    bench.add_argument("--note", default=None,
                       help="a remark on the machine recorded in the JSON (its load is "
                            "recorded anyway, and a busy machine is noted)")
    bench.add_argument("--pareto", action="store_true",
                       help="run the experiment `pareto` (every registered method, run time "
                            "against error) at --size into --root/figures and print its "
                            "Pareto fronts; --render-only prints them from the existing JSON")
    bench.add_argument("--render-only", action="store_true",
                       help="with --pareto: do not run, print the fronts of "
                            "figures/pareto.json")
    bench.add_argument("--root", default=".", help="with --pareto: repository root (default: .)")

    figures = sub.add_parser("figures", help="regenerate the figures of experiments/")
    figures.add_argument("--size", choices=("ci", "full"), default="ci")
    figures.add_argument("--only", action="append", default=[], metavar="NAME",
                         help="only this experiment (repeatable)")
    figures.add_argument("--root", default=".", help="repository root (default: .)")
    figures.add_argument("--workers", type=int, default=None,
                         help="run the experiments on a local Dask cluster of N processes")
    figures.add_argument("--scheduler", metavar="ADDRESS",
                         help="run the experiments on the Dask cluster at ADDRESS")
    figures.add_argument("--quiet", action="store_true")
    figures.add_argument("--fresh", action="store_true",
                         help="discard the finished sweep points that an interrupted run "
                              "kept in figures/.checkpoints (by default a re-run of the "
                              "same code and config resumes them)")
    figures.add_argument("--claims-only", action="store_true",
                         help="run nothing: recompute the claims of the figures in "
                              "--root/figures from their stored arrays and configs (after a "
                              "change to an experiment's claims())")
    return ap


def _cmd_run(args) -> int:
    from .config import load_config
    from .harness.run import format_table, run

    config = load_config(args.config, args.overrides)
    out = run(config, out_dir=args.out, progress=not args.quiet)
    print(format_table(out.metrics))
    for path in out.files:
        print(f"wrote {path}")
    return 0


def _cmd_sweep(args) -> int:
    from .config import ConfigError
    from .harness.sweep import SweepError, load_sweep, run_sweep

    if args.workers is not None and args.workers < 1:
        raise ConfigError(f"sweep --workers must be >= 1, got {args.workers}")
    if args.repeats < 0:
        raise ConfigError(f"sweep --repeats must be >= 0, got {args.repeats}")
    if args.workers is not None and args.scheduler:
        raise ConfigError("sweep: --workers starts a local cluster and --scheduler uses an "
                          "existing one; give one of them")
    sweep = load_sweep(args.config, args.overrides, repeats=args.repeats)
    out = args.out or sweep.configs[0].output.dir
    try:
        result = run_sweep(sweep, out, workers=args.workers, scheduler=args.scheduler,
                           progress=not args.quiet)
    except SweepError as exc:
        print(f"shadowlab: {exc}", file=sys.stderr)
        print(f"wrote {Path(out) / 'results.parquet'} (finished tasks only)")
        return 1
    print(f"{len(result.table)} rows ({result.ran} tasks run, {result.already_done} "
          f"already done)")
    print(f"wrote {result.path}")
    return 0


def _cmd_methods(args) -> int:
    from .methods import available

    for name, info in available().items():
        kind = "soft" if info["soft"] else ("exact" if info["exact"] else "approximate")
        print(f"{name}  [{kind}]  {info['doc']}")
        for opt, spec in info["options"].items():
            print(f"    {opt} = {spec['default']!r}  ({spec['allowed']})  {spec['doc']}")
        if info["static_options"]:
            print("    static (shadowlab bench, static light and geometry): " + ", ".join(
                f"{k}={v!r}" for k, v in info["static_options"].items()))
    return 0


def _cmd_scenes(args) -> int:
    from .scene.procedural import GENERATORS

    for name, gen in GENERATORS.items():
        print(f"{name}  {gen.doc}")
        print("    " + ", ".join(f"{k}={v!r}" for k, v in gen.defaults.items()))
    return 0


def _cmd_pareto(args) -> int:
    """``bench --pareto``: the experiment ``pareto`` run (or only read) and its fronts
    printed as the README quotes them."""
    import json

    from .config import ConfigError
    from .harness.figures import run_experiment
    from .harness.pareto_readme import render_block

    if args.config or args.only or args.overrides:
        raise ConfigError("bench --pareto runs the experiment config "
                          "configs/experiments/pareto.<size>.toml; it takes no config, "
                          "--only or --set")
    root = Path(args.root)
    path = root / "figures" / "pareto.json"
    if not args.render_only:
        run_experiment(root, "pareto", args.size)
    elif not path.exists():
        raise ConfigError(f"bench --pareto --render-only: {path} does not exist; run "
                          "shadowlab bench --pareto first")
    print(render_block(json.loads(path.read_text())))
    print(f"wrote {root / 'figures'}/pareto.{{png,npz,json}}" if not args.render_only
          else f"read {path}")
    return 0


def _cmd_cold(args) -> int:
    from .config import ConfigError
    from .core import io
    from .harness.cold_start import cold_start, format_cold

    if args.pareto or args.only:
        raise ConfigError("bench --cold measures the methods of one run config (CONFIG, "
                          "or the built-in default, with --set); it takes no --pareto or "
                          "--only (choose methods with --set methods.names=[...])")
    if args.repeats < 1:
        raise ConfigError(f"bench --repeats must be >= 1, got {args.repeats}")
    if args.size != "full":
        raise ConfigError("bench --cold measures one run config; --size (of the built-in "
                          "cases) does not apply")
    results = cold_start(args.config, args.overrides, repeats=args.repeats,
                         progress=not args.quiet, note=args.note)
    out = args.out or "cold_start.json"
    io.write_json(out, results)
    print(format_cold(results))
    print(f"wrote {out}")
    return 1 if any("failed" in r for r in results["methods"].values()) else 0


def _cmd_bench(args) -> int:
    from .harness.bench import default_cases, format_bench, run_bench
    from .config import ConfigError, load_config

    if args.render_only and not args.pareto:
        raise ConfigError("bench --render-only needs --pareto")
    if args.cold:
        return _cmd_cold(args)
    if args.pareto:
        return _cmd_pareto(args)
    args.out = args.out or "bench.json"
    if args.config:
        configs = [load_config(args.config, args.overrides)]
        names = [args.config]
    else:
        cases = default_cases(args.size)
        known = [c["name"] for c in cases]
        unknown = sorted(set(args.only) - set(known))
        if unknown:
            raise ConfigError(f"bench --only: unknown case(s) {', '.join(unknown)}; "
                              f"{args.size} cases: {', '.join(known)}")
        cases = [c for c in cases if not args.only or c["name"] in args.only]
        configs = [load_config(None, list(c["overrides"]) + args.overrides) for c in cases]
        names = [c["name"] for c in cases]
    if args.repeats < 1:
        raise ConfigError(f"bench --repeats must be >= 1, got {args.repeats}")
    results = run_bench(configs, repeats=args.repeats, out=args.out, progress=not args.quiet,
                        names=names, note=args.note)
    print(format_bench(results))
    print(f"wrote {args.out}")
    return 0


def _cmd_figures(args) -> int:
    from .harness.figures import regenerate, remeasure_claims

    from .config import ConfigError

    if args.claims_only and args.fresh:
        raise ConfigError("figures --claims-only runs nothing, so --fresh (discard "
                          "checkpointed points) does not apply; give one of them")
    if args.claims_only:
        for name in remeasure_claims(Path(args.root), only=args.only or None):
            if not args.quiet:
                print(f"{name}: claims recomputed", file=sys.stderr)
        return 0

    if args.workers is not None and args.workers < 1:
        raise ConfigError(f"figures --workers must be >= 1, got {args.workers}")
    if args.workers is not None and args.scheduler:
        raise ConfigError("figures: give --workers (a local cluster) or --scheduler (an "
                          "existing one), not both")
    failures = regenerate(Path(args.root), size=args.size, only=args.only,
                          progress=not args.quiet, workers=args.workers,
                          scheduler=args.scheduler, fresh=args.fresh)
    return 1 if failures else 0


def main(argv: list[str] | None = None) -> int:
    from .config import ConfigError
    from .core.capacity import CapacityError
    from .harness.figures import ExperimentError
    from .core.heap import set_heap_policy
    from .core.jaxcache import enable_compilation_cache
    from .methods import MethodError
    from .scene import SceneError

    args = _parser().parse_args(argv)
    try:
        set_heap_policy(args.heap)
    except ValueError as exc:          # $SHADOWLAB_HEAP names no policy
        print(f"shadowlab: error: {exc}", file=sys.stderr)
        return 2
    enable_compilation_cache()
    handlers = {"run": _cmd_run, "sweep": _cmd_sweep, "methods": _cmd_methods,
                "scenes": _cmd_scenes,
                "bench": _cmd_bench, "figures": _cmd_figures}
    try:
        return handlers[args.command](args)
    except (ConfigError, ExperimentError, MethodError, SceneError, CapacityError) as exc:
        print(f"shadowlab: error: {exc}", file=sys.stderr)
        return 2
    except MemoryError as exc:      # past the up-front estimate (shadowlab.config.resources)
        print(f"shadowlab: error: out of memory ({exc or 'MemoryError'}); lower "
              "camera.resolution or animation.frames, or set SHADOWLAB_MEMORY_LIMIT lower so "
              "such work is refused up front; no output file was written", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("shadowlab: interrupted; no output file was left half-written"
              + (" (finished sweep tasks are kept and a re-run skips them)"
                 if args.command == "sweep" else
                 " (finished sweep points are kept in figures/.checkpoints and a re-run "
                 "resumes them)" if args.command == "figures" else ""), file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())

