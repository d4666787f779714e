"""`terl-rt replay`: list the episodes of an MCAP log, show one, verify it bit for bit."""

from __future__ import annotations

import json

import click

from terl_rt.cli.live import live_option, open_live
from terl_rt.cli.options import BadInput, FloatRange, episode_option, json_option, policy_json
from terl_rt.files import OutputHold
from terl_rt.logs.held import held_logs
from terl_rt.logs.live import stream_log
from terl_rt.logs.reader import EpisodeLogReader, LoggedEpisode
from terl_rt.logs.resimulate import verify


def _episode_dict(entry: LoggedEpisode) -> dict:
    return {
        "episode": entry.number, "index": entry.index, "scenario": entry.scenario.name, "evader": entry.scenario.evader,
        "seed": entry.seed,
        "steps": entry.steps, "complete": entry.complete, "damaged_chunks": list(entry.damaged),
        "metrics": None if entry.metrics is None else entry.metrics.to_dict(),
        "shield_overrides": None if entry.metrics is None else entry.metrics.shield_overrides,
    }


def _shield_line(entries: list[LoggedEpisode]) -> str | None:
    """The overrides of the listed episodes that ran under the shield, in one line; None without any."""
    shielded = [e.metrics for e in entries if e.metrics is not None and e.metrics.shield_overrides is not None]
    if not shielded:
        return None
    overrides, decisions = sum(m.shield_overrides for m in shielded), sum(m.decisions for m in shielded)
    return (f"shield: {overrides:,} overrides in {decisions:,} pursuer-steps of {len(shielded)} shielded episode(s)"
            f" ({overrides / max(decisions, 1):.4f} a pursuer-step)")


def _per_pursuer(counts) -> str:
    """Pursuers the shield overrode and how often, e.g. "3 x 2, 7 x 1"; "none"."""
    return ", ".join(f"{i} x {n}" for i, n in enumerate(counts.tolist()) if n) or "none"


MIN_RATE, MAX_RATE = 0.01, 1000.0
"""--rate's range: a hundredth of real time to a thousand times it."""

LIST_HEADER = (
    f"{'#':>4}  {'scenario':<14}{'seed':>6}{'steps':>7}  {'outcome':<8}{'travel (s)':>11}{'encircled':>10}"
    f"{'collision ratio':>16}{'return':>10}"
)
"""The columns of the episode list: one per field of `_episode_line`."""


def _episode_line(entry: LoggedEpisode) -> str:
    if entry.metrics is None:
        outcome = "cut off (no end recorded)"
    else:
        m = entry.metrics
        team_return = "-" if m.team_return is None else f"{m.team_return:.1f}"  # logs from before returns
        outcome = (
            f"{'success' if m.success else 'failure':<8}{m.travel_time_s:>11.1f}{m.evaders_encircled:>10}"
            f"{m.collision_ratio:>16.3f}{team_return:>10}"
        )
    damage = f"  DAMAGED: reads up to the chunk at byte {entry.damaged[0]}" if entry.damaged else ""
    return f"{entry.number:>4}  {entry.scenario.label:<14}{entry.seed:>6}{entry.steps:>7}  {outcome}{damage}"


def _notes(log: str, reader: EpisodeLogReader) -> list[str]:
    """What is said under the output about `log`: that a run is still writing it, what it
    lost (cut off, damaged chunks), and the side logs beside it (terl_rt.logs.held): those
    of the episodes a running batched run holds back for their turn, or that a killed one left."""
    writer = OutputHold.holder(log)
    notes = [] if writer is None else [f"a run (pid {writer}) is still writing this log: it reads as far as it is written"]
    if reader.problem:
        notes.append(reader.problem)
    held = held_logs(log)
    if held:
        where = f"each a log of its own: {held[0].parent}/ (terl-rt replay {held[0]})"
        notes.append(f"{len(held)} more episode(s) wait beside the log for their turn, {where}" if writer is not None
                     else f"the run was killed with {len(held)} more episode(s) held beside the log, {where}")
    return notes


@click.command()
@click.argument("log", type=str)
@episode_option
@click.option("--verify", "check", is_flag=True, help="Re-simulate and compare every recorded state bit for bit.")
@json_option
@live_option("Stream the episodes (every one, or --episode K) at their log times, once a client subscribes to /world,")
@click.option(
    "--rate", type=FloatRange(MIN_RATE, MAX_RATE), default=None, metavar="X",
    help="With --live: how many times real time the log plays (0.5 s steps) [default: 1, real time].",
)
def replay(log: str, episode: int | None, check: bool, as_json: bool, live: tuple[str, int] | None,
           rate: float | None) -> None:
    """List the episodes of an MCAP episode log (from `terl-rt eval --log`), show the
    events of one (--episode K; under --shield, how often it overrode each pursuer), or
    verify episodes by re-simulating them (--verify:
    every episode, or K). Exit status 1 when a verification finds a mismatch. A batched
    run holds the episodes waiting for their turn in LOG.held/, one log each, and a killed
    one leaves them there; the notes under the list name them, and a run still writing LOG.
    --live serves the log to Foxglove as a run's --live serves it, paced by its log times
    (--rate X plays it X times faster), and ends with the last step.

    \b
    Examples:
      terl-rt replay run.mcap                        # one line per episode
      terl-rt replay run.mcap --episode 3            # its captures, collisions and end
      terl-rt replay run.mcap --verify               # re-simulate every episode bit for bit
      terl-rt replay run.mcap --episode 3 --json
      terl-rt replay run.mcap --live --rate 4        # to Foxglove at ws://127.0.0.1:8765, 4x real time
    """
    if rate is not None and live is None:
        raise BadInput("--rate sets the pace of --live; pass --live with it")
    if live is not None and (check or as_json):
        raise BadInput("--live streams the log; pass --verify and --json without it")
    reader = EpisodeLogReader(log)
    chosen = list(range(len(reader.episodes))) if episode is None else [reader.episode(episode).number]
    if live is not None:
        with open_live(live) as sink:
            click.echo("waiting for a client to subscribe to /world", err=True)
            sink.wait_watched()
            sent = stream_log(reader, sink, chosen, 1.0 if rate is None else rate)
        click.echo(f"streamed {sent} steps of {len(chosen)} episode(s) of {log}")
        for note in _notes(log, reader):
            click.echo(f"note: {note}", err=True)
        return
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
            for note in _notes(log, reader):
                click.echo(f"note: {note}", err=True)
        if not all(r.ok for r in reports):
            click.get_current_context().exit(1)
        return

    entries = [reader.episode(number) for number in chosen]
    events = []
    overrides = None
    if episode is not None:
        events = [
            {"step": step.step, **event} for step in reader.steps(episode) for event in step.events
        ]
        overrides = reader.shield_overrides(episode)
    if as_json:
        out = {
            "log": log, "policy": policy_json(reader.policy),
            "truncated": reader.truncated, "problem": reader.problem,
            "episodes": [_episode_dict(entry) for entry in entries],
            "held_logs": [str(path) for path in held_logs(log)],
        }
        if episode is not None:
            out["events"] = events
            out["shield_overrides_by_pursuer"] = None if overrides is None else overrides.tolist()
        click.echo(json.dumps(out))
        return
    click.echo(f"log {log}: policy {reader.policy['name']} (sha256 {reader.policy['sha256'][:12]})")
    click.echo(LIST_HEADER)
    for entry in entries:
        click.echo(_episode_line(entry))
    if _shield_line(entries):
        click.echo(_shield_line(entries))
    if overrides is not None:
        click.echo(f"shield overrode, by pursuer (steps): {_per_pursuer(overrides)}")
    if episode is not None:
        click.echo("events:" if events else "events: none")
        for event in events:
            details = ", ".join(f"{k} {v}" for k, v in event.items() if k not in ("step", "type"))
            click.echo(f"  step {event['step']:>5}  {event['type']:<12} {details}")
    for note in _notes(log, reader):
        click.echo(f"note: {note}", err=True)
