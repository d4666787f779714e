"""`terl-rt sweep`: several policies x scenarios x seeds into one results table."""

from __future__ import annotations

import csv
import io
import json
import sys
from pathlib import Path

import click

from terl_rt.cli.eval import terl_rt_version
from terl_rt.cli.options import (
    acting_of,
    check_acting,
    episodes_option,
    json_option,
    open_policies,
    policies_option,
    policy_threads,
    progressbar,
    resolve_scenarios,
    run_backend,
    run_options,
    scenario_file_option,
    scenarios_option,
    suite_option,
)
from terl_rt.cli.outputs import check_output, force_option, output_folder
from terl_rt.evaluation.sweep import TABLE_COLUMNS, Sweep, run_sweep, sweep_json, sweep_markdown, table_rows
from terl_rt.files import atomic_output

TABLE_FILES = ("sweep.json", "sweep.csv", "sweep.md")
"""What a sweep writes into --out: the full results (every episode), the table as CSV and as markdown."""


def table_texts(sweep: Sweep, header: dict) -> dict[str, str]:
    """The text of each of TABLE_FILES; `header` opens the JSON (version, seed, backend)."""
    table = io.StringIO()
    writer = csv.DictWriter(table, fieldnames=TABLE_COLUMNS, lineterminator="\n")
    writer.writeheader()
    writer.writerows(table_rows(sweep))
    return {
        "sweep.json": json.dumps({**header, **sweep_json(sweep)}, indent=1) + "\n",
        "sweep.csv": table.getvalue(),
        "sweep.md": sweep_markdown(sweep),
    }


def write_tables(texts: dict[str, str], out_dir: Path, replace: bool = False) -> list[Path]:
    """Write each text into `out_dir` whole (`atomic_output`); replace: replace existing files."""
    paths = []
    for name, text in texts.items():
        path = out_dir / name
        with atomic_output(path, replace) as staging:
            staging.write_text(text)
        paths.append(path)
    return paths


@click.command("sweep")
@policies_option
@scenarios_option
@scenario_file_option
@suite_option
@episodes_option
@run_options
@click.option(
    "--out", type=str, default="sweep", show_default=True, metavar="DIR",
    help="Folder to write sweep.json, sweep.csv and sweep.md to (made if missing).",
)
@json_option
@force_option
def sweep_command(
    policy_paths, scenario_names, scenario_file, suite, evader, episodes, seed, max_steps, workers, backend, address,
    threads, out, shield, shield_margin, shield_horizon, risk, as_json, force,
) -> None:
    """Evaluate several policies on several scenarios, the same seeds each (episode k
    with seed + k), as one batch of episodes, and write one results table: DIR/sweep.md
    and DIR/sweep.csv (a row per policy and scenario: success rate, travel time, collision
    ratio with 95 % bootstrap intervals, steps) and DIR/sweep.json (every episode too).
    With --backend ray every episode is a Ray task, the whole sweep submitted at once, so
    a cluster stays busy; the table is the same on either backend. A progress bar goes to
    stderr. Existing files are replaced only with --force. --shield and --risk make every
    policy act so (docs/safety.md); each row names it ("terl [shield 0.5 m / 4 steps]").

    \b
    Examples:
      terl-rt sweep --policy a.onnx --policy b.onnx --scenario small-15 --scenario medium-48 --out sweep
      terl-rt sweep --policy policies/ --suite paper --episodes 20 --workers 2 --out sweep --force
      terl-rt sweep --policy policies/ --suite paper --backend ray --address auto --out sweep
    """
    out_dir = output_folder(out)
    scenarios = resolve_scenarios(scenario_names, scenario_file, suite, evader)
    acting = acting_of(shield, shield_margin, shield_horizon, risk)
    policies = open_policies(policy_paths, threads=policy_threads(backend, workers, threads))
    for policy in policies:
        check_acting(acting, policy)
    inputs = [("--policy", policy.path) for policy in policies] + [("--scenario-file", scenario_file)]
    for name in TABLE_FILES:
        check_output(out_dir / name, "--out", inputs, force)
    total = len(policies) * len(scenarios) * episodes
    with run_backend(backend, workers, address, threads) as runner, progressbar(
        length=total, label="sweep", file=sys.stderr, show_pos=True, show_eta=True,
    ) as bar:
        sweep = run_sweep(
            policies, scenarios, episodes, seed, runner, max_steps=max_steps, progress=lambda number, metrics: bar.update(1),
            acting=acting,
        )
    header = {"terl_rt": terl_rt_version(), "episodes": episodes, "seed": seed, "backend": backend,
              "acting": {**acting.to_dict(), "label": acting.label}}
    # The results reach the terminal first: a full disk cannot lose them.
    if as_json:
        click.echo(json.dumps({**header, **sweep_json(sweep)}))
    else:
        click.echo(f"{len(policies)} policies x {len(scenarios)} scenarios x {episodes} episodes (seed {seed}), "
                   f"{sweep.wall_s:.1f} s on {backend}")
        click.echo(sweep_markdown(sweep), nl=False)
    paths = write_tables(table_texts(sweep, header), out_dir, replace=force)
    if not as_json:
        click.echo(f"wrote {', '.join(str(path) for path in paths)}")
