"""The resumable runner of a comparison: several policies evaluated on the same scenarios,
each (policy, scenario) result kept as it finishes (`saved_results`), so that the same
comparison run again after a cut-off (Ctrl-C, a machine's end) evaluates only what is left.

The caller says how one evaluation runs (`Evaluate`: its backend, its progress bar) and
where the runner's lines go (`say`); it writes the files from the runs returned
(`comparison.write_comparison`, `seed_comparison_files.write_seed_comparison`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from datetime import datetime, timezone
from functools import partial
from pathlib import Path

from terl_rt.evaluation.episodes import ScenarioResult
from terl_rt.paper import comparison, seed_comparison_files
from terl_rt.paper.comparison import DEFAULT_TERL, MethodRun, method_name, paper_order
from terl_rt.paper.saved_results import SavedResults
from terl_rt.paper.seed_comparison import SeedRun, check_seeds, policy_identity, seed_statistics
from terl_rt.policy.contract import META_METHOD, META_SEED
from terl_rt.policy.onnx_policy import OnnxPolicy, policy_info
from terl_rt.sim.scenario import Scenario

PROGRESS_FOLDER = ".report-progress"
"""The folder in the output folder that keeps a comparison's finished evaluations until its
files are written."""

METHOD_FILES = {"markdown": comparison.MARKDOWN_NAME, "figure": comparison.FIGURE_NAME, "json": comparison.JSON_NAME}
"""What a comparison of one policy a method writes, by role."""
SEED_FILES = dict(zip(("figure", "markdown", "json", "marl_eval"), seed_comparison_files.OUTPUT_NAMES))
"""What a comparison over training seeds writes, by role, in the order it is published."""

Evaluate = Callable[[OnnxPolicy, Scenario, int], ScenarioResult]
"""(policy, scenario with its step limit in force, episodes) -> that evaluation's result,
episode k with the comparison's seed + k."""


def over_seeds(policies: Sequence[OnnxPolicy]) -> bool:
    """Whether several policies are compared over training seeds: one carries terl.method
    or terl.seed, or two are of one method."""
    methods = [method_name(policy.name) for policy in policies]
    return len(set(methods)) < len(methods) or any(
        META_METHOD in policy.metadata or META_SEED in policy.metadata for policy in policies
    )


def seeds_in_paper_order(policies: Sequence[OnnxPolicy],
                         terl: str = DEFAULT_TERL) -> list[tuple[str, int | None, OnnxPolicy]]:
    """(method, training seed or None, policy) of each policy (`policy_identity`, `terl` the
    stem that stands for TERL), in the paper's order of methods, then by seed. ValueError (a
    ComparisonError among them) for two policies that cannot be told apart, or a terl.seed
    that is no integer."""
    named = [(*policy_identity(policy.metadata, terl), policy) for policy in policies]
    check_seeds([(method, seed, str(policy.path)) for method, seed, policy in named])
    return sorted(named, key=lambda item: (paper_order(item[0]), -1 if item[1] is None else item[1]))


@dataclass(frozen=True)
class FinishedComparison:
    """A comparison evaluated, its files not yet written."""

    files: Mapping[str, str]
    """role (markdown, figure, json, marl_eval) -> the name of the file it writes."""
    data: dict
    """its JSON form (comparison.json)."""
    claims: list[tuple[str, str]]
    """(verdict, claim) of each of the paper's claims, in the paper's order."""
    write: Callable[[Path], object]
    """writes `files` into a folder."""


@dataclass(frozen=True)
class ComparisonRunner:
    """Evaluates a comparison's policies on its scenarios, each result saved in
    `out_dir`/PROGRESS_FOLDER as it finishes, or read back where an earlier run saved it."""

    out_dir: Path
    """the comparison's output folder."""
    seed: int
    """episode k of every evaluation runs with seed + k."""
    max_steps: int | None
    """step limit of every scenario (decision steps of 0.5 s); None: each scenario's own."""
    evaluate: Evaluate
    """how one evaluation runs (the caller's backend and progress bar)."""
    say: Callable[[str], None] = lambda line: None
    """where the runner's lines go (the policy it starts, a result read back)."""

    @property
    def saved(self) -> SavedResults:
        """Where each (policy, scenario) result is kept as it finishes, until the outputs are written."""
        return SavedResults(self.out_dir / PROGRESS_FOLDER)

    def note_saved(self) -> None:
        """Say how many results an earlier, cut-off run of the comparison left."""
        if count := self.saved.count():
            self.say(f"{count} results of an earlier run in {self.saved.folder}: those evaluations are read back, "
                     "not run again")

    def results(self, policy: OnnxPolicy, scenarios: Sequence[Scenario], episodes: int) -> list[ScenarioResult]:
        """One policy's results on `scenarios`, `episodes` each: each saved as it finishes, or
        read back where an earlier run saved it."""
        results = []
        for scenario in scenarios:
            if self.max_steps is not None:
                scenario = scenario.replace(max_steps=self.max_steps)
            result = self.saved.load(policy.sha256, scenario, episodes, self.seed)
            if result is None:
                result = self.evaluate(policy, scenario, episodes)
                self.saved.save(policy.sha256, scenario, result)
            else:
                self.say(f"{scenario.name:<14} {episodes} episodes read back from {self.saved.folder}")
            results.append(result)
        return results

    def method_runs(self, policies: Sequence[OnnxPolicy], scenarios: Sequence[Scenario],
                    episodes: int) -> list[MethodRun]:
        """Each policy (one a method) evaluated on `scenarios`, in the paper's order of methods."""
        self.note_saved()
        methods = sorted(((method_name(policy.name), policy) for policy in policies),
                         key=lambda pair: paper_order(pair[0]))
        runs = []
        for method, policy in methods:
            self.say(f"{method}: {policy.path}")
            runs.append(MethodRun(method, policy_info(policy), tuple(self.results(policy, scenarios, episodes))))
        return runs

    def seed_runs(self, named: Sequence[tuple[str, int | None, OnnxPolicy]], scenarios: Sequence[Scenario],
                  episodes: int, worlds: Sequence[Scenario] = (), world_episodes: int = 0) -> list[SeedRun]:
        """Each (method, seed, policy) of `named` (`seeds_in_paper_order`) evaluated on
        `scenarios`, `episodes` each, then on `worlds` (past the paper's), `world_episodes` each."""
        self.note_saved()
        runs = []
        for number, (method, seed, policy) in enumerate(named, start=1):
            self.say(f"[{number}/{len(named)}] {method} seed {seed}: {policy.path}")
            results = self.results(policy, scenarios, episodes) + self.results(policy, worlds, world_episodes)
            runs.append(SeedRun(method, seed, policy_info(policy), tuple(results)))
        return runs

    def compare_methods(self, policies: Sequence[OnnxPolicy], scenarios: Sequence[Scenario], episodes: int,
                        command: str) -> FinishedComparison:
        """The comparison of policies one a method (`method_runs`) as the paper compares them;
        command: the command line that runs it, as the files quote it."""
        runs = self.method_runs(policies, scenarios, episodes)
        date = datetime.now(timezone.utc)
        data = comparison.comparison_dict(runs, command, date)
        claims = [(check["verdict"], check["claim"]) for check in data["claims"]]
        return FinishedComparison(METHOD_FILES, data, claims,
                                  partial(comparison.write_comparison, runs, command=command, date=date))

    def compare_seeds(self, named: Sequence[tuple[str, int | None, OnnxPolicy]], scenarios: Sequence[Scenario],
                      episodes: int, worlds: Sequence[Scenario], world_episodes: int,
                      command: str) -> FinishedComparison:
        """The comparison over training seeds (`seed_runs`, the arguments theirs): means, IQMs
        and claims over seeds; command: the command line that runs it, as the files quote it."""
        runs = self.seed_runs(named, scenarios, episodes, worlds, world_episodes)
        date = datetime.now(timezone.utc)
        stats = seed_statistics(runs)
        data = seed_comparison_files.seed_comparison_dict(runs, stats, command, date)
        claims = [(check.verdict, check.claim) for check in stats.claims]
        return FinishedComparison(SEED_FILES, data, claims, partial(
            seed_comparison_files.write_seed_comparison, runs, command=command, date=date, stats=stats))

    def finish(self, keep: bool) -> None:
        """The comparison's files are written: remove the saved results, unless `keep`
        (a later comparison with more policies reads them back)."""
        if not keep:
            self.saved.remove()
