"""`terl-rt replay`: list the episodes of an MCAP log, show one, verify it bit for bit."""

from __future__ import annotations

import json

import click

from terl_rt.cli.options import episode_option, json_option, policy_json
from terl_rt.logs.reader import EpisodeLogReader, LoggedEpisode
from terl_rt.logs.resimulate import verify


def _episode_dict(entry: LoggedEpisode) -> dict:
    return {
        "episode": entry.number, "index": entry.index, "scenario": entry.scenario.name, "seed": entry.seed,
        "steps": entry.steps, "complete": entry.complete,
        "metrics": None if entry.metrics is None else entry.metrics.to_dict(),
    }


def _episode_line(entry: LoggedEpisode) -> str:
    if entry.metrics is None:
        outcome = "cut off (no end recorded)"
    else:
        m = entry.metrics
        outcome = (
            f"{'success' if m.success else 'failure':<8} {m.travel_time_s:>8.1f} s "
            f"encircled {m.evaders_encircled:>3}  collision ratio {m.collision_ratio:.3f}"
        )
    return f"{entry.number:>4}  {entry.scenario.name:<14}{entry.seed:>6}{entry.steps:>7}  {outcome}"


@click.command()
@click.argument("log", type=str)
@episode_option
@click.option("--verify", "check", is_flag=True, help="Re-simulate and compare every recorded state bit for bit.")
@json_option
def replay(log: str, episode: int | None, check: bool, as_json: bool) -> None:
    """List the episodes of an MCAP episode log (from `terl-rt eval --log`), show the
    events of one (--episode K), or verify episodes by re-simulating them (--verify:
    every episode, or K). Exit status 1 when a verification finds a mismatch."""
    reader = EpisodeLogReader(log)
    chosen = list(range(len(reader.episodes))) if episode is None else [reader.episode(episode).number]
    if check:
        reports = [verify(log, number) for number in chosen]
        if as_json:
            click.echo(json.dumps({
                "log": log, "truncated": reader.truncated, "problem": reader.problem,
                "ok": all(r.ok for r in reports), "episodes": [r.to_dict() for r in reports],
            }))
        else:
            for report in reports:
                click.echo(report.format())
            if reader.problem:
                click.echo(f"note: {reader.problem}", err=True)
        if not all(r.ok for r in reports):
            click.get_current_context().exit(1)
        return

    entries = [reader.episode(number) for number in chosen]
    events = []
    if episode is not None:
        events = [
            {"step": step.step, **event} for step in reader.steps(episode) for event in step.events
        ]
    if as_json:
        out = {
            "log": log, "policy": policy_json(reader.policy),
            "truncated": reader.truncated, "problem": reader.problem,
            "episodes": [_episode_dict(entry) for entry in entries],
        }
        if episode is not None:
            out["events"] = events
        click.echo(json.dumps(out))
        return
    click.echo(f"log {log}: policy {reader.policy['name']} (sha256 {reader.policy['sha256'][:12]})")
    click.echo(f"{'#':>4}  {'scenario':<14}{'seed':>6}{'steps':>7}  outcome")
    for entry in entries:
        click.echo(_episode_line(entry))
    if episode is not None:
        click.echo("events:" if events else "events: none")
        for event in events:
            details = ", ".join(f"{k} {v}" for k, v in event.items() if k not in ("step", "type"))
            click.echo(f"  step {event['step']:>5}  {event['type']:<12} {details}")
    if reader.problem:
        click.echo(f"note: {reader.problem}", err=True)
