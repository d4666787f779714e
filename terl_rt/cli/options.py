"""Options shared by several terl-rt subcommands, defined once."""

from __future__ import annotations

import errno
import os
import stat
import sys
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager, redirect_stdout
from pathlib import Path
from typing import Any

import click

from terl_rt.command_line import address_option  # noqa: F401 (shared with python -m training)
from terl_rt.evaluation.backends import BACKENDS, RayMissing, open_backend
from terl_rt.evaluation.episodes import Progress
from terl_rt.evaluation.evaluate import Evaluation, LogTarget, evaluate
from terl_rt.evaluation.runs import Backend
from terl_rt.policy import shipped
from terl_rt.policy.onnx_policy import OnnxPolicy
from terl_rt.policy.shipped import DEFAULT_POLICY, NoShippedPolicy
from terl_rt.safety.acting import Acting
from terl_rt.safety.risk import Risk
from terl_rt.safety.shield import DEFAULT_HORIZON_STEPS, DEFAULT_MARGIN_M, MAX_HORIZON_STEPS, MAX_MARGIN_M, Shield
from terl_rt.sim.evader import DEFAULT_EVADER, EVADERS, UnknownEvader, evader_kind
from terl_rt.sim.scenario import PAPER_SUITE, SCENARIO_LIMITS, Scenario

MAX_SEED = 2**62
"""largest --seed: seed + k stays a 64-bit integer for any number of episodes."""
MAX_THREADS = 256
"""largest --threads."""
MAX_WORKERS = 64
"""largest --workers (each worker holds its own onnxruntime session)."""
MAX_EPISODES = 1_000_000
"""largest --episodes."""
MAX_STEPS = SCENARIO_LIMITS["max_steps"]
"""largest --max-steps: the scenario field's own limit."""


def _readable(bound: float) -> str:
    """A range bound as people write it: 2^62, 10^6, else the number itself."""
    if isinstance(bound, int) and bound > 2**20 and bound & (bound - 1) == 0:
        return f"2^{bound.bit_length() - 1}"
    if isinstance(bound, int) and bound >= 10**5 and str(bound).rstrip("0") == "1":
        return f"10^{len(str(bound)) - 1}"
    return f"{bound:g}" if isinstance(bound, float) else str(bound)


class _ReadableRange:
    """A click range type whose bounds --help and errors print readably: "0 to 2^62"."""

    def _describe_range(self) -> str:
        if self.min is None:
            return f"at most {_readable(self.max)}"
        if self.max is None:
            return f"at least {_readable(self.min)}"
        return f"{_readable(self.min)} to {_readable(self.max)}"


class IntRange(_ReadableRange, click.IntRange):
    """click's IntRange with bounds printed readably in --help and errors: "0 to 2^62"."""


class FloatRange(_ReadableRange, click.FloatRange):
    """click's FloatRange with bounds printed readably in --help and errors: "0 to 10"."""


class BadInput(click.ClickException):
    """An expected user mistake: printed as one line "Error: ...", exit status 2."""

    exit_code = 2


def _scenario(ctx: click.Context, param: click.Parameter, value: str | None) -> Scenario | None:
    # ScenarioError propagates: the terl-rt group prints it as one line, exit 2.
    return None if value is None else Scenario.preset(value)


def _evader(ctx: click.Context, param: click.Parameter, value: str | None) -> str | None:
    if value is not None:
        try:
            evader_kind(value)
        except UnknownEvader as error:
            raise BadInput(f"--evader: {error}") from None
    return value


def open_policy(path: str | None, threads: int | None = None) -> OnnxPolicy:
    """Open the policy file `path` (None: the default policy, `terl_rt.policy.shipped`);
    contract refusals name the file."""
    try:
        return shipped.open_policy(None if path is None else Path(path), threads=threads)
    except NoShippedPolicy as error:
        raise BadInput(f"{error}; pass --policy") from None


def policy_files(given: tuple[str, ...]) -> list[str | None]:
    """The policy files of a repeated --policy, in order: a file as given, a folder's *.onnx
    files by name; [None] (the default policy) when none is given. BadInput for a folder
    without one, or with a *.onnx that is no regular file (it is never skipped unseen)."""
    if not given:
        return [None]
    files: list[str | None] = []
    for path in given:
        if Path(path).is_dir():
            found = sorted(Path(path).glob("*.onnx"))
            if not found:
                raise BadInput(f"--policy {path} is a folder without .onnx files")
            for file in found:
                kind = _not_a_file(file)
                if kind is not None:
                    raise BadInput(f"--policy {path}: {file.name} is {kind}, not a policy file; remove it or "
                                   "name the policies one by one")
            files += map(str, found)
        else:
            files.append(path)
    return files


def _not_a_file(path: Path) -> str | None:
    """What `path` is, in words, when it is no regular file ("a FIFO", "a broken link to X");
    None for a regular file."""
    try:
        mode = path.stat().st_mode
    except OSError as error:
        if error.errno == errno.ELOOP:
            return "a symlink loop"
        return f"a broken link to {os.readlink(path)}" if path.is_symlink() else f"unreadable ({error.strerror})"
    if stat.S_ISREG(mode):
        return None
    return "a folder" if stat.S_ISDIR(mode) else "a FIFO" if stat.S_ISFIFO(mode) else "a device or a socket"


def open_policies(paths: tuple[str, ...], threads: int | None = None) -> list[OnnxPolicy]:
    """Open the policies of a repeated --policy (`policy_files`), in order."""
    return [open_policy(file, threads=threads) for file in policy_files(paths)]


def policy_json(info: Mapping[str, Any]) -> dict[str, str]:
    """The policy in --json output: name, sha256 and path of a `policy_info` (or of a log's policy)."""
    return {key: info[key] for key in ("name", "sha256", "path")}


def resolve_scenarios(
    names: tuple[str, ...], scenario_file: str | None, suite: str | None, evader: str | None = None,
) -> list[Scenario]:
    """The scenarios of `--scenario ... | --scenario-file F | --suite paper` (default small-15),
    with the evader of --evader (`with_evader`)."""
    given = sum(bool(choice) for choice in (names, scenario_file, suite))
    if given > 1:
        raise BadInput("pass only one of --scenario, --scenario-file and --suite")
    if scenario_file:
        return with_evader([Scenario.from_file(scenario_file)], evader)
    if suite:
        return with_evader([Scenario.preset(name) for name in PAPER_SUITE], evader)
    return with_evader([Scenario.preset(name) for name in (names or ("small-15",))], evader)


def with_evader(scenarios: list[Scenario], evader: str | None) -> list[Scenario]:
    """`scenarios` with the evader of --evader, `evader` (None: each its own)."""
    return scenarios if evader is None else [scenario.replace(evader=evader) for scenario in scenarios]


def check_address(backend: str, address: str | None) -> None:
    """BadInput for an --address without --backend ray."""
    if address is not None and backend != "ray":
        raise BadInput("--address names a Ray cluster; pass --backend ray with it")


def run_backend(name: str, workers: int | None, address: str | None, threads: int | None) -> Backend:
    """The backend of --backend, --workers, --address and --threads (`open_backend`), ready
    to run; a missing Ray or a misplaced --address is BadInput (a cluster that cannot be
    reached is a BackendError, which the terl-rt group prints as one line too)."""
    check_address(name, address)
    try:
        return open_backend(name, workers, address, threads)
    except RayMissing as error:
        raise BadInput(str(error)) from None


def policy_threads(backend: str, workers: int | None, threads: int | None) -> int | None:
    """onnxruntime threads of the policy opened in this process: --threads when the
    episodes run here (local backend, one worker), else onnxruntime's default (the
    workers open their own)."""
    return threads if backend == "local" and (workers or 1) == 1 else None


def progressbar(*args: Any, **kwargs: Any) -> Any:
    """click.progressbar (its arguments; file: stderr unless given), hidden where that file is
    no terminal (a log file, a pipe), where it would print its label alone, without a bar."""
    kwargs.setdefault("file", sys.stderr)
    return click.progressbar(*args, hidden=not kwargs["file"].isatty(), **kwargs)


@contextmanager
def progress_bar(scenario: Scenario, episodes: int) -> Iterator[Progress]:
    """A progress bar on stderr for one scenario's episodes (`terl_rt.evaluate`'s progress)."""
    with progressbar(length=episodes, label=f"{scenario.name:<14}", show_pos=True, show_eta=True) as bar:
        yield lambda index, metrics: bar.update(1)


def evaluate_with_progress(
    policy: OnnxPolicy,
    scenarios: list[Scenario],
    episodes: int,
    seed: int,
    max_steps: int | None = None,
    log: LogTarget | Sequence[LogTarget] | None = None,
    replace_log: bool = True,
    workers: int | None = None,
    backend: Backend | str = "local",
    address: str | None = None,
    threads: int | None = None,
    acting: Acting = Acting(),
) -> Evaluation:
    """`terl_rt.evaluate` with a progress bar per scenario on stderr; the arguments are
    evaluate's (`acting` its shield and risk). A missing Ray or a misplaced --address is BadInput."""
    if isinstance(backend, str):
        check_address(backend, address)
    check_acting(acting, policy)
    try:
        return evaluate(policy, scenarios, episodes, seed, max_steps=max_steps, log=log, replace_log=replace_log,
                        workers=workers, backend=backend, address=address, threads=threads, progress=progress_bar,
                        shield=acting.shield, risk=acting.risk)
    except RayMissing as error:
        raise BadInput(str(error)) from None


def acting_of(shield: bool, margin_m: float | None, horizon_steps: int | None, risk: str | None) -> Acting:
    """The acting rule of --shield, --shield-margin, --shield-horizon and --risk; BadInput for
    a shield parameter without --shield or a --risk that does not parse."""
    if not shield and (margin_m is not None or horizon_steps is not None):
        raise BadInput("--shield-margin and --shield-horizon set the shield's parameters; pass --shield with them")
    try:
        return Acting(
            Shield(DEFAULT_MARGIN_M if margin_m is None else margin_m,
                   DEFAULT_HORIZON_STEPS if horizon_steps is None else horizon_steps) if shield else None,
            None if risk is None else Risk.parse(risk),
        )
    except ValueError as error:
        raise BadInput(str(error)) from None


def check_acting(acting: Acting, policy: Any) -> None:
    """BadInput when `acting` cannot act with `policy` (--risk for a policy without quantiles)."""
    try:
        acting.check(policy)
    except ValueError as error:
        raise BadInput(str(error)) from None


def acting_options(command):
    """--shield, --shield-margin, --shield-horizon and --risk, stacked in this order; the
    command gets them as `shield`, `shield_margin`, `shield_horizon` and `risk` (`acting_of`)."""
    options = (
        click.option(
            "--shield", is_flag=True,
            help="Act under the decentralised shield: each pursuer drops the actions whose predicted clearance "
            "to what it sees falls below the margin (docs/safety.md). Results name the rows it ran.",
        ),
        click.option(
            "--shield-margin", type=FloatRange(0.0, MAX_MARGIN_M), default=None, metavar="M",
            help=f"m: the clearance an action must keep, with --shield [default: {DEFAULT_MARGIN_M:g}].",
        ),
        click.option(
            "--shield-horizon", type=IntRange(1, MAX_HORIZON_STEPS), default=None, metavar="STEPS",
            help=f"Decision steps (0.5 s) the shield predicts, with --shield [default: {DEFAULT_HORIZON_STEPS}].",
        ),
        click.option(
            "--risk", type=str, default=None, metavar="cvar:ALPHA",
            help="Act on the mean of the lowest ALPHA share of each action's quantiles (CVaR) instead of all of "
            "them, e.g. cvar:0.25; needs a policy with the quantiles output (docs/safety.md).",
        ),
    )
    for option in reversed(options):
        command = option(command)
    return command


scenario_option = click.option(
    "--scenario", "scenario", default="small-15", show_default=True, callback=_scenario,
    help="Preset scenario name (see `terl-rt scenarios`).",
)
scenarios_option = click.option(
    "--scenario", "scenario_names", multiple=True, metavar="NAME",
    help="Preset scenario (repeat for several; default small-15; see `terl-rt scenarios`).",
)
scenario_file_option = click.option(
    "--scenario-file", type=str, default=None, metavar="FILE",
    help="A JSON scenario file instead of presets: the form `terl-rt scenarios --json NAME` prints for a preset "
    "(the terl-rt repository's docs/world.md section 12).",
)
suite_option = click.option(
    "--suite", type=click.Choice(["paper"]), default=None,
    help="A scenario suite: paper = the 10 evaluation presets of Table III.",
)
evader_option = click.option(
    "--evader", default=None, metavar="NAME", callback=_evader,
    help=f"The evaders of every scenario: {', '.join(EVADERS)} (`terl-rt scenarios --evaders`) "
    f"[default: the scenario's own, {DEFAULT_EVADER} (the paper's) for the presets].",
)
seed_option = click.option(
    "--seed", type=IntRange(min=0, max=MAX_SEED), default=0, show_default=True,
    help="Random seed of the episodes.",
)
json_option = click.option(
    "--json", "as_json", is_flag=True, help="Print one JSON object instead of a table."
)


@contextmanager
def stdout_kept_for_json(as_json: bool) -> Iterator[None]:
    """With --json (`as_json`), what is printed to stdout inside the block goes to stderr,
    so that stdout holds the JSON alone: Ray prints its workers' lines and a dying worker's
    `(raylet)` report to the driver's stdout, until it shuts down."""
    if not as_json:
        yield
        return
    with redirect_stdout(sys.stderr):
        yield
policy_option = click.option(
    "--policy", "policy_path", type=str, default=None, metavar="PATH",
    help=f"ONNX policy file [default: {DEFAULT_POLICY} of the checkout, else the copy installed with terl-rt].",
)
policies_option = click.option(
    "--policy", "policy_paths", multiple=True, metavar="PATH",
    help="ONNX policy file, or a folder of them (its *.onnx, by name); repeat for several "
    f"[default: {DEFAULT_POLICY} of the checkout, else the copy installed with terl-rt].",
)
threads_option = click.option(
    "--threads", type=IntRange(min=1, max=MAX_THREADS), default=None,
    help="onnxruntime intra-op threads [default: onnxruntime's choice; 1 per worker].",
)
def _episodes_option(default: int):
    return click.option(
        "--episodes", type=IntRange(min=1, max=MAX_EPISODES), default=default, show_default=True,
        help="Episodes per scenario; episode k runs with seed + k.",
    )


episodes_option = _episodes_option(20)
report_episodes_option = _episodes_option(100)
"""`terl-rt report`'s: 100 episodes a preset (batched, minutes on 2 cores), where the paper ran 20."""
max_steps_option = click.option(
    "--max-steps", type=IntRange(min=1, max=MAX_STEPS), default=None,
    help="Step limit per episode (0.5 s steps) [default: the scenario's, 1000].",
)
workers_option = click.option(
    "--workers", type=IntRange(min=1, max=MAX_WORKERS), default=None,
    help="Processes to spread the episodes over, or with --backend ray the episodes run at once "
    "(results are the same as with 1) [default: 1; with --backend ray: every CPU of the cluster].",
)
backend_option = click.option(
    "--backend", type=click.Choice(BACKENDS), default="local", show_default=True,
    help="Where the episodes run: local (this machine) or ray (Ray tasks: a local Ray instance, "
    "or the cluster at --address; pip install 'terl-rt[ray]'). Results and logs are the same.",
)
log_option = click.option(
    "--log", "log_path", type=str, default=None, metavar="FILE.mcap",
    help="Write every step of every episode to this MCAP log (Foxglove, replay, render).",
)
episode_option = click.option(
    "--episode", type=IntRange(min=0), default=None,
    help="Episode of the log, by its position in the file (0-based).",
)


def evaluation_run_options(command):
    """The options that say what a timed evaluation runs, stacked in this order: --policy,
    --scenario (repeatable), --suite, --episodes, --seed, --max-steps (`bench eval`, `bench backends`)."""
    for option in reversed(
        (policy_option, scenarios_option, suite_option, episodes_option, seed_option, max_steps_option)
    ):
        command = option(command)
    return command


def run_options(command):
    """The options that say how a command's episodes run, shared by `eval`, `sweep` and `report`,
    stacked in this order: --evader, --seed, --max-steps, --workers, --backend, --address,
    --threads and the acting options (`acting_options`)."""
    for option in reversed((
        evader_option, seed_option, max_steps_option, workers_option, backend_option, address_option, threads_option,
        acting_options,
    )):
        command = option(command)
    return command
