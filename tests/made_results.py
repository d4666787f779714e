"""Hand-made evaluation results (no simulation) for the report and comparison tests.

`made_result` builds a ScenarioResult from per-episode outcomes chosen so its means are
known: `successes` of `episodes` succeed, every episode lasts `travel_s` seconds
(+- `spread_s` alternately, so the mean stays `travel_s`) and has `collided` of 20
pursuers collided. Its 95 % intervals come from the bootstrap as in a real run.
"""

from __future__ import annotations

from terl_rt.evaluation.episodes import ScenarioResult
from terl_rt.sim.metrics import EpisodeMetrics, summarize

PURSUERS = 20
"""Team size behind every made collision ratio: `collided` / 20."""


def made_result(name: str, successes: int = 20, travel_s: float = 40.0, collided: int = 0,
                episodes: int = 20, spread_s: float = 5.0, max_steps: int = 1000) -> ScenarioResult:
    """A ScenarioResult of `episodes` made episodes: the first `successes` succeed; travel
    time (s) alternates travel_s +- spread_s (an odd count ends on travel_s); collision
    ratio collided / 20 in every episode."""
    per_episode = []
    for k in range(episodes):
        offset = 0.0 if (episodes % 2 and k == episodes - 1) else (spread_s if k % 2 else -spread_s)
        travel = travel_s + offset
        per_episode.append(EpisodeMetrics(
            success=k < successes, steps=round(travel / 0.5), travel_time_s=travel,
            collision_ratio=collided / PURSUERS, evaders_encircled=1, pursuers_collided=collided,
        ))
    summary = summarize(per_episode)
    return ScenarioResult(
        name=name, episodes=episodes, seed=0, max_steps=max_steps, success_rate=summary.success_rate,
        travel_time_s_mean=summary.travel_time_s_mean, travel_time_s_std=summary.travel_time_s_std,
        collision_ratio_mean=summary.collision_ratio_mean, steps_mean=summary.steps_mean, wall_s=0.0,
        per_episode=tuple(per_episode),
    )
