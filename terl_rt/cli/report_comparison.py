"""`terl-rt report` with several policies, or --beyond: the comparison's options as given, its
resumable run (terl_rt.paper.runner), its claims' verdicts on the terminal and its files."""

from __future__ import annotations

import json
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import click

from terl_rt.cli.options import BadInput, evaluate_with_progress, resolve_scenarios, run_backend, with_evader
from terl_rt.cli.outputs import check_output
from terl_rt.evaluation.episodes import ScenarioResult
from terl_rt.files import atomic_outputs
from terl_rt.paper import seed_comparison
from terl_rt.paper.comparison import DEFAULT_TERL
from terl_rt.paper.numbers import TERL
from terl_rt.paper.report import REPORT_SUITE
from terl_rt.paper.runner import (
    METHOD_FILES,
    PROGRESS_FOLDER,
    SEED_FILES,
    ComparisonRunner,
    over_seeds,
    seeds_in_paper_order,
)
from terl_rt.policy.onnx_policy import OnnxPolicy
from terl_rt.sim.scenario import Scenario


@dataclass(frozen=True)
class ComparisonRun:
    """The options of a `terl-rt report` that compares several policies, as given."""

    scenario_names: tuple[str, ...]
    episodes: int
    beyond_episodes: int
    """episodes in each world past the paper's (`seed_comparison.beyond_scenarios`)."""
    seed: int
    max_steps: int | None
    workers: int | None
    backend: str
    address: str | None
    threads: int | None
    out_dir: Path
    keep_progress: bool
    """keep the runner's saved results once the files are written."""
    as_json: bool
    force: bool
    command: str
    """the command line, as the written files quote it."""
    terl: str = DEFAULT_TERL
    """the recipe stem of the method that stands for the paper's TERL (--terl)."""
    evader: str | None = None
    """the evaders of every scenario (--evader; None: each scenario's own)."""

    @contextmanager
    def runner(self) -> Iterator[ComparisonRunner]:
        """The resumable runner of these options: its evaluations on their backend, each with a
        progress bar, its lines on stderr."""
        with run_backend(self.backend, self.workers, self.address, self.threads) as backend:
            def evaluate(policy: OnnxPolicy, scenario: Scenario, episodes: int) -> ScenarioResult:
                (result,) = evaluate_with_progress(policy, [scenario], episodes, self.seed, backend=backend).results
                return result

            yield ComparisonRunner(self.out_dir, self.seed, self.max_steps, evaluate, lambda line: click.echo(line, err=True))


def compare(policies: list[OnnxPolicy], beyond: bool, run: ComparisonRun) -> None:
    """`terl-rt report` with several policies (or --beyond): over training seeds where
    `over_seeds` says so or with `beyond`, else one policy a method; evaluate each in the
    paper's order of methods (then by seed), print the claims' verdicts and write the files.
    A method other than terl standing for TERL (`run.terl`) makes it over seeds too."""
    seeds = beyond or run.terl != DEFAULT_TERL or over_seeds(policies)
    files = SEED_FILES if seeds else METHOD_FILES
    for name in files.values():
        check_output(run.out_dir / name, "--out", [("--policy", policy.path) for policy in policies], run.force)
    progress = run.out_dir / PROGRESS_FOLDER
    if (progress.exists() or progress.is_symlink()) and not progress.is_dir():  # said now, not at the first result
        raise BadInput(f"--out {run.out_dir}: {progress} is not a folder, and the comparison keeps its evaluations "
                       "there as they finish; move it away")
    scenarios = resolve_scenarios(run.scenario_names or REPORT_SUITE, None, None, run.evader)
    if seeds:
        try:
            named = seeds_in_paper_order(policies, run.terl)
        except ValueError as error:  # ComparisonError, or a terl.seed that is no integer
            raise BadInput(f"--policy: {error}") from error
        if run.terl != DEFAULT_TERL and TERL not in {method for method, _, _ in named}:
            stems = sorted({seed_comparison.method_stem(policy.metadata) for policy in policies})
            raise BadInput(f"--terl {run.terl}: no policy is of that method (their methods: {', '.join(stems)})")
        worlds = with_evader(seed_comparison.beyond_scenarios(), run.evader) if beyond else []
        with run.runner() as runner:
            finished = runner.compare_seeds(named, scenarios, run.episodes, worlds, run.beyond_episodes, run.command)
    else:
        with run.runner() as runner:
            finished = runner.compare_methods(policies, scenarios, run.episodes, run.command)
    paths = {role: str(run.out_dir / name) for role, name in finished.files.items()}
    # The results reach the terminal before any file is written: a full disk cannot lose them.
    if run.as_json:
        click.echo(json.dumps({**finished.data, "files": paths}))
    else:
        for verdict, claim in finished.claims:
            click.echo(f"{verdict:<19} {claim}")
    with atomic_outputs(run.out_dir, tuple(finished.files.values()), replace=run.force) as staging:
        finished.write(staging)
    runner.finish(run.keep_progress)
    if not run.as_json:
        wrote = [paths[role] for role in ("markdown", "figure", "json", "marl_eval") if role in paths]
        click.echo(f"wrote {', '.join(wrote[:-1])} and {wrote[-1]}")
