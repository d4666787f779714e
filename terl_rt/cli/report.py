"""`terl-rt report`: evaluate a policy on the paper's presets and write docs/results.md and .png;
several policies: docs/comparison.md, .png and .json (over training seeds: and the
marl-eval export), run by terl_rt.cli.report_comparison."""

from __future__ import annotations

import json
import shlex
import textwrap

import click

from terl_rt.cli.options import (
    BadInput,
    acting_of,
    evaluate_with_progress,
    json_option,
    open_policy,
    policies_option,
    policy_files,
    policy_json,
    policy_threads,
    report_episodes_option,
    resolve_scenarios,
    run_options,
)
from terl_rt.cli.outputs import check_output, force_option, output_folder
from terl_rt.cli.report_comparison import ComparisonRun, compare
from terl_rt.files import atomic_outputs
from terl_rt.paper import seed_comparison
from terl_rt.paper.comparison import DEFAULT_TERL
from terl_rt.paper.figures import MatplotlibMissing, require_matplotlib
from terl_rt.paper.report import (
    FIGURE_NAME,
    MARKDOWN_NAME,
    REPORT_SUITE,
    ReportPaths,
    goal_checks,
    group_summaries,
    where_it_stands,
    write_report,
)
from terl_rt.policy.onnx_policy import policy_info
from terl_rt.safety.acting import Acting


def command_line(
    policy_paths: tuple[str, ...],
    scenario_names: tuple[str, ...],
    episodes: int,
    seed: int,
    max_steps: int | None,
    workers: int | None,
    threads: int | None,
    out: str,
    force: bool = False,
    backend: str = "local",
    address: str | None = None,
    beyond: bool = False,
    beyond_episodes: int | None = None,
    terl: str = DEFAULT_TERL,
    acting: Acting = Acting(),
    evader: str | None = None,
) -> str:
    """The `terl-rt report` command line that repeats a run, every option that shapes the results spelled out."""
    words = ["terl-rt", "report"]
    for path in policy_paths:
        words += ["--policy", path]
    for name in scenario_names:
        words += ["--scenario", name]
    if evader is not None:
        words += ["--evader", evader]
    if beyond:
        words.append("--beyond")
    if terl != DEFAULT_TERL:
        words += ["--terl", terl]
    words += ["--episodes", str(episodes)]
    if beyond_episodes is not None:
        words += ["--beyond-episodes", str(beyond_episodes)]
    words += ["--seed", str(seed)]
    if max_steps is not None:
        words += ["--max-steps", str(max_steps)]
    if workers is not None:
        words += ["--workers", str(workers)]
    if backend != "local":
        words += ["--backend", backend]
    if address is not None:
        words += ["--address", address]
    if threads is not None:
        words += ["--threads", str(threads)]
    if acting.shield is not None:
        words += ["--shield", "--shield-margin", f"{acting.shield.margin_m:g}",
                  "--shield-horizon", str(acting.shield.horizon_steps)]
    if acting.risk is not None:
        words += ["--risk", acting.risk.label]
    words += ["--out", out]
    if force:
        words.append("--force")
    return shlex.join(words)


@click.command("report")
@policies_option
@click.option(
    "--scenario", "scenario_names", multiple=True, metavar="NAME",
    help="Preset scenario (repeat for several) [default: the 10 paper presets and the 3 small-published "
    "ones; see `terl-rt scenarios`].",
)
@click.option(
    "--beyond", is_flag=True,
    help="Also evaluate teams past the paper's: "
    f"{', '.join(str(n) for n in seed_comparison.BEYOND_PURSUERS)} pursuers in `terl-rt bench scaling`'s worlds "
    "(large-80's grown, evaders a quarter of the pursuers, the same density); writes the comparison over "
    "seeds, even of one policy. A 400-pursuer step costs the simulator about 6 large-80 steps and the policy 5 "
    "times the rows (docs/benchmarks.md).",
)
@click.option(
    "--terl", default=DEFAULT_TERL, show_default=True, metavar="METHOD",
    help="The method (a recipe stem, as terl.method names it) that stands for the paper's TERL: the claims are "
    "judged on its seeds and P(TERL better) is its. Another than terl makes the run a comparison over seeds, "
    "in which method terl keeps its own name: --terl terl-authors sets the authors' protocol as TERL beside "
    "the 1 M protocol's seeds (docs/training.md).",
)
@report_episodes_option
@click.option(
    "--beyond-episodes", type=click.IntRange(min=1, max=10**6), default=None, metavar="N",
    help="Episodes in each world past the paper's, with --beyond [default: --episodes]: fewer keep a grid's "
    "report short, an episode there costing several of large-80's (see --beyond).",
)
@run_options
@click.option(
    "--out", type=str, default="report", show_default=True, metavar="DIR",
    help="Folder to write results.md and results.png to (made if missing).",
)
@click.option(
    "--keep-progress", is_flag=True,
    help="Keep a comparison's DIR/.report-progress once its files are written: a later comparison with more "
    "policies (a grid's seeds as they ship) reads those evaluations back. They are found by the policy file's "
    "bytes, the scenario, the episodes and the seed, not by the simulator's code: remove the folder after "
    "changing that.",
)
@json_option
@force_option
def report_command(
    policy_paths, scenario_names, evader, beyond, terl, episodes, beyond_episodes, seed, max_steps, workers, backend,
    address, threads, shield, shield_margin, shield_horizon, risk, out, keep_progress, as_json, force,
) -> None:
    """Measure a policy against the TERL paper: evaluate it on the paper's presets and
    the released small-scale config's, and write DIR/results.md (a row per preset and per
    scale group beside the paper's TERL numbers, and which of the paper's goals are met)
    and DIR/results.png (success rate, travel time and collision ratio against the
    number of pursuers). The figure needs matplotlib: pip install 'terl-rt[report]'. A
    progress bar goes to stderr. Existing results files (the shipped docs/results.*
    included) are replaced only with --force, and only once both new files are complete.

    Several policies (--policy repeated, or a folder) are compared as the paper compares
    TERL, IQN, DQN, MEAN, w/o RE and w/o TS (method names from each file's terl.model):
    DIR/comparison.md (the paper's claims checked, Table III on CC, Table IV the
    ablation, each beside the paper's numbers, with 95 % intervals), DIR/comparison.png
    (Fig. 3: one line a method) and DIR/comparison.json.

    Several training seeds of a method (files with terl.method and terl.seed metadata, as
    a grid exports them to exported/comparison/<method>-seed-<S>.onnx; or two files of
    one method whose terl.training_config seeds differ), --beyond or --terl make it a comparison
    over seeds: per method and scale group the mean and interquartile mean over seeds with
    95 % stratified bootstrap intervals and the probability that TERL does better; the
    paper's claims judged on them (reproduces, does not reproduce, or cannot tell where the
    intervals overlap); each seed alone against the paper's goals (success with its exact
    interval, travel time and collision ratio per scale group, goals met, successes past 80
    pursuers); a bar figure in the form of Fig. 3; and every episode in marl-eval's JSON
    format, DIR/comparison-marl-eval.json.

    A comparison keeps each policy's result on each scenario in DIR/.report-progress as it
    finishes: the same command run again after a cut-off (a session's end, Ctrl-C) reads
    them back and evaluates only what is left; the folder goes once the files are written
    (unless --keep-progress).

    --shield and --risk (one policy only: the paper's comparison stays as the paper ran it)
    evaluate the policy acting so (docs/safety.md); the page and the figure name it.

    \b
    Examples:
      terl-rt report                                   # the default policy into ./report
      terl-rt report --policy my.onnx --episodes 5 --workers 2 --out my-report
      terl-rt report --policy policies/ --scenario cc-28 --out comparison
      terl-rt report --policy exported/comparison --episodes 50 --workers 2 --out docs --force
      terl-rt report --policy exported/comparison --beyond --scenario small-15 --episodes 10 --out /tmp/beyond
      terl-rt report --policy exported/comparison --beyond --episodes 50 --beyond-episodes 10 --workers 2 --out docs --force
      terl-rt report --policy exported/comparison --episodes 50 --workers 2 --out docs --force --keep-progress
      terl-rt report --policy exported/comparison --terl terl-authors --episodes 50 --workers 2 --out authors
    """
    try:
        require_matplotlib()  # before the evaluation, which may take hours
    except MatplotlibMissing as error:
        raise BadInput(str(error)) from error
    if beyond_episodes is not None and not beyond:
        raise BadInput("--beyond-episodes: the worlds past the paper's are evaluated only with --beyond")
    out_dir = output_folder(out)
    files = policy_files(policy_paths)
    acting = acting_of(shield, shield_margin, shield_horizon, risk)
    command = command_line(
        policy_paths, scenario_names, episodes, seed, max_steps, workers, threads, out, force, backend, address, beyond,
        beyond_episodes, terl, acting, evader,
    )
    if len(files) > 1 or beyond or terl != DEFAULT_TERL:
        if not acting.plain:
            raise BadInput("--shield and --risk evaluate one policy: the paper's comparison runs every policy as the "
                           "paper did (greedy); compare shielded rows with `terl-rt sweep --shield`")
        policies = [open_policy(path, threads=policy_threads(backend, workers, threads)) for path in files]
        run = ComparisonRun(scenario_names, episodes, beyond_episodes or episodes, seed, max_steps, workers, backend,
                            address, threads, out_dir, keep_progress, as_json, force, command, terl, evader)
        compare(policies, beyond, run)
        return
    if keep_progress:
        raise BadInput("--keep-progress: only a comparison (several policies, or --beyond) keeps its evaluations")
    policy_path = files[0]
    for name in (MARKDOWN_NAME, FIGURE_NAME):
        check_output(out_dir / name, "--out", [("--policy", policy_path)], force)
    scenarios = resolve_scenarios(scenario_names or REPORT_SUITE, None, None, evader)
    policy = open_policy(policy_path, threads=policy_threads(backend, workers, threads))
    results = evaluate_with_progress(policy, scenarios, episodes, seed, max_steps=max_steps, workers=workers,
                                     backend=backend, address=address, threads=threads, acting=acting).results
    info = policy_info(policy)
    paths = ReportPaths(markdown=out_dir / MARKDOWN_NAME, figure=out_dir / FIGURE_NAME)
    # The results reach the terminal before any file is written: a full disk cannot lose them.
    if as_json:
        click.echo(json.dumps({
            "policy": policy_json(info),
            "acting": {**acting.to_dict(), "label": acting.label},
            "scenarios": [result.to_dict() for result in results],
            "groups": [summary.to_dict() for summary in group_summaries(results)],
            "goals": [check.to_dict() for check in goal_checks(results)],
            "files": {"markdown": str(paths.markdown), "figure": str(paths.figure)},
        }))
    else:
        acted = f" [{acting.label}]" if acting.label else ""
        click.echo(f"policy {policy.name}{acted} ({policy.path}, sha256 {policy.sha256[:12]}), seed {seed}")
        click.echo(textwrap.fill(where_it_stands(results), width=100))
    with atomic_outputs(out_dir, (FIGURE_NAME, MARKDOWN_NAME), replace=force) as staging:
        write_report(results, info, staging, command)
    if not as_json:
        click.echo(f"wrote {paths.markdown} and {paths.figure}")
