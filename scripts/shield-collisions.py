"""What each collision left under the shield was (docs/safety.md, "What collisions remain").

    python scripts/shield-collisions.py [--policy P] [--scenario S]... [--episodes N] [--seed K]

Runs the shielded policy (the shield's defaults) on each scenario's episodes K..K+N-1 (the
sweep's episodes), one world an episode, and sorts every pursuer that collides by what the
shield knew at the decision of the step it collided in:

- "none kept": every action was predicted to come closer than the shield keeps (the margin, or
  the clearance of the moment where that is less); the shield took the action of largest
  clearance and it was not enough;
- "predicted clear": the action taken was predicted to keep the margin. Then what was touched
  moved otherwise than the pursuer's observation said: a teammate is split by what its own
  shield did in that step (overrode its policy, or found no action it kept), an evader and an
  obstacle stand alone (an evader turns or speeds up; an obstacle stands still, so that is the
  unobserved current or the fallback's path).

Each kind is split by what the pursuer touched; for "none kept", the decisions in a row it had
kept none before it collided (1: boxed in at the last decision alone). Markdown on stdout: one
table, a row a scenario, counts of collided pursuers.
"""

from __future__ import annotations

import argparse
from collections import Counter

import numpy as np

from terl_rt.policy.onnx_policy import OnnxPolicy
from terl_rt.safety.shield import Shield, safety_scores, shielded_actions
from terl_rt.sim.collisions import TOUCHED_EVADER, TOUCHED_TEAMMATE
from terl_rt.sim.scenario import Scenario
from terl_rt.sim.world import World

KINDS = (
    "none kept: teammate", "none kept: evader", "none kept: obstacle",
    "predicted clear: teammate, its shield overrode", "predicted clear: teammate, none kept by its shield",
    "predicted clear: teammate, its policy's action", "predicted clear: evader", "predicted clear: obstacle",
)
"""The table's columns, in order."""


def touched_name(touched: int) -> str:
    """What a collided pursuer's TOUCHED_* bits name first: teammate, evader or obstacle."""
    return "teammate" if touched & TOUCHED_TEAMMATE else "evader" if touched & TOUCHED_EVADER else "obstacle"


def kind_of(touched: int, scores: np.ndarray, partners: list[tuple[bool, bool]]) -> str:
    """The KINDS entry of one collided pursuer: what it touched (TOUCHED_* bits), its action
    scores [A] m at the step's decision (the shield takes a kept action whenever there is one),
    and (overridden, none kept) for each teammate it touched."""
    name = touched_name(touched)
    if not (scores >= 0).any():
        return f"none kept: {name}"
    if name == "teammate":
        if any(none for _, none in partners):
            return "predicted clear: teammate, none kept by its shield"
        if any(overrode for overrode, _ in partners):
            return "predicted clear: teammate, its shield overrode"
        return "predicted clear: teammate, its policy's action"
    return f"predicted clear: {name}"


def touching_teammates(world: World, pursuer: int) -> np.ndarray:
    """The pursuers whose discs touch `pursuer`'s after the step (env 0), itself left out."""
    state, params = world.state, world.params
    xy = state.pursuer_xy[0]
    near = np.linalg.norm(xy - xy[pursuer], axis=-1) <= 2 * params.robot_radius + 1e-9
    near[pursuer] = False
    return np.flatnonzero(near)


def episode_kinds(policy: OnnxPolicy, scenario: Scenario, seed: int, shield: Shield) -> tuple[Counter, list[int]]:
    """The KINDS of every pursuer that collides in episode `seed` of `scenario`, shielded, and
    for each that collided with no action kept, the decisions in a row it had none kept."""
    world = World(scenario, num_envs=1, seed=seed)
    observation = world.reset()
    kinds: Counter = Counter()
    boxed = np.zeros(scenario.pursuers, np.int64)  # decisions in a row with no action kept
    runs: list[int] = []
    while not world.done[0]:
        active = np.flatnonzero(world.state.pursuer_active[0])
        rows = observation.rows(active)
        output = policy.evaluate(rows)
        scores = safety_scores(rows, scenario.params, shield)
        chosen = shielded_actions(output.actions, output.q_values, scores)
        actions = np.zeros(scenario.pursuers, np.int64)
        actions[active] = chosen
        overridden = dict(zip(active.tolist(), (chosen != output.actions).tolist()))
        none = ~(scores >= 0).any(axis=-1)
        none_kept = dict(zip(active.tolist(), none.tolist()))
        boxed[active] = np.where(none, boxed[active] + 1, 0)
        row_of = {int(p): k for k, p in enumerate(active)}
        observation, result = world.step(actions[None])
        for pursuer in np.flatnonzero(result.collided[0]):
            k = row_of[int(pursuer)]
            touched = int(world.state.pursuer_touched[0, pursuer])
            partners = [(overridden.get(int(q), False), none_kept.get(int(q), False))
                        for q in touching_teammates(world, int(pursuer))]
            kind = kind_of(touched, scores[k], partners)
            kinds[kind] += 1
            if kind.startswith("none kept"):
                runs.append(int(boxed[pursuer]))
    return kinds, runs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policy", default="exported/terl.onnx")
    parser.add_argument("--scenario", action="append", help="a preset (default: medium-48, large-80, cc-28)")
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    policy = OnnxPolicy(args.policy, threads=1)
    shield = Shield()
    print(f"Collided pursuers under the shield ({shield.label}), `{args.policy}`, episodes "
          f"{args.seed}-{args.seed + args.episodes - 1} of each scenario:\n")
    print("| scenario | collided | " + " | ".join(KINDS) + " | none kept: decisions in a row, median (max) |")
    print("|---|---:|" + "---:|" * (len(KINDS) + 1))
    for name in args.scenario or ["medium-48", "large-80", "cc-28"]:
        scenario = Scenario.preset(name)
        kinds: Counter = Counter()
        runs: list[int] = []
        for seed in range(args.seed, args.seed + args.episodes):
            episode, boxed = episode_kinds(policy, scenario, seed, shield)
            kinds += episode
            runs += boxed
        in_a_row = f"{np.median(runs):.0f} ({max(runs)})" if runs else "—"
        print(f"| {name} | {sum(kinds.values())} | " + " | ".join(str(kinds[kind]) for kind in KINDS) + f" | {in_a_row} |")


if __name__ == "__main__":
    main()
