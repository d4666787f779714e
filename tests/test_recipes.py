"""Recipes (recipes/*.toml): each shipped policy made by one file, and the runner that makes it,
resuming a recipe cut off where it stopped."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import re
import shutil
from pathlib import Path

import pytest

from terl_rt.sim.scenario import curriculum_stage
from training.__main__ import main
from training.checkpoint import read_counters
from training.config import NETWORK_FIELDS
from training.lab.recipe import CARRIED_FIELDS, RecipeError, load_recipe, run_recipe, segment_folder

ROOT = Path(__file__).parents[1]
TINY = ROOT / "tests" / "data" / "tiny-recipe.toml"
RECIPES = sorted((ROOT / "recipes").rglob("*.toml"))
NOT_YET_SHIPPED = {
    *(f"comparison-scale/{method}.toml" for method in ("terl", "iqn", "dqn", "mean", "terl-no-re", "terl-no-ts")),
    "scale-fine-tune-x1.toml",
}
"""Recipes (from recipes/) whose runs are training (issues 77 and 74): their seeds ship when they end."""


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


# ---------------------------------------------------------------- the shipped recipes
def test_every_recipe_loads_and_ships_a_file_of_the_repository():
    assert len(RECIPES) >= 7
    for path in RECIPES:
        if path.relative_to(ROOT / "recipes").as_posix() in NOT_YET_SHIPPED:
            load_recipe(path)
            continue
        shipped = ROOT / load_recipe(path).ships
        # A recipe run once ships its file; one run over seeds by the grid ships <stem>-seed-<S>.onnx.
        ships = shipped.is_file() or any(shipped.parent.glob(f"{shipped.stem}-seed-*.onnx"))
        assert ships, f"{path}: ships {shipped.relative_to(ROOT)}, which is not in the repository"


def test_the_comparison_recipes_are_terl_papers_with_only_the_network_changed():
    paper = load_recipe(ROOT / "recipes" / "terl-paper.toml")
    assert paper.segments[-1].config.schedule.total_steps >= 1_000_000
    for path in sorted((ROOT / "recipes" / "comparison").glob("*.toml")):
        recipe = load_recipe(path)
        assert recipe.ships_from == paper.ships_from, path
        assert [(s.name, s.start, s.refill) for s in recipe.segments] == [(s.name, s.start, s.refill) for s in paper.segments]
        for ours, theirs in zip(recipe.segments, paper.segments):
            assert ours.config.network.model == path.stem
            assert ours.config.replace(**{name: theirs.config.value(name) for name in NETWORK_FIELDS}) == theirs.config, path


def test_the_authors_recipe_is_the_published_trainer_on_the_compact_network():
    recipe = load_recipe(ROOT / "recipes" / "terl-authors.toml")
    assert (recipe.ships, recipe.ships_from, len(recipe.segments)) == ("exported/comparison/terl-authors.onnx", "last", 1)
    config = recipe.segments[0].config
    network, learner, data, schedule, run = config.network, config.learner, config.data, config.schedule, config.run
    assert (network.model, network.hidden, network.layers, network.heads, network.dropout) == ("terl", 64, 2, 4, 0.1)
    assert (learner.learning_rate, learner.batch_size, learner.train_frequency, learner.max_grad_norm) == (1e-4, 128, 4, 0.5)
    assert (learner.target_network_frequency, learner.gamma, learner.num_quantiles, learner.num_target_quantiles) == (
        10_000, 0.99, 8, 8)
    assert (learner.double_dqn, learner.actor_update_frequency, learner.final_learning_rate) == (False, 0, 0.0)
    assert (data.reward, data.reward_scale, data.potential_shaping, data.collision_value) == ("published", 1.0, 0.0, 0.0)
    assert (data.success_ends_transitions, data.buffer_size, data.learning_starts, data.store_pursuers) == (
        False, 1_000_000, 3000, 0)
    assert (schedule.total_steps, schedule.train_max_steps, schedule.start_e, schedule.end_e) == (7_000_000, 3000, 0.6, 0.05)
    assert schedule.exploration_fraction * schedule.total_steps == 1_750_000
    # The stages start at 2, 4, 5 and 6 M: the published time_steps [0, 2 M, 4 M, 5 M, 6 M].
    span = schedule.curriculum_steps or schedule.total_steps
    steps = (0, 1_999_999, 2_000_000, 3_999_999, 4_000_000, 4_999_999, 5_000_000, 5_999_999, 6_000_000, 6_999_999)
    assert schedule.curriculum and [curriculum_stage(step, span).name[-1] for step in steps] == list("1122334455")
    assert (run.snapshot_frequency, run.snapshot_episodes, run.eval_seed, run.keep_snapshots) == (500_000, 10, 6000, True)


def test_every_shipped_policy_card_names_its_recipe_and_the_sha256_of_its_weights():
    # A grid's seed (<method>-seed-<S>.onnx) is on its method's card, whose recipe is <method>.toml.
    for onnx in sorted((ROOT / "exported").rglob("*.onnx")):
        seed = re.fullmatch(r"(.+)-seed-\d+", onnx.stem)
        card = onnx.with_name(f"{seed.group(1)}.md" if seed else f"{onnx.stem}.md").read_text()
        shipped = onnx.relative_to(ROOT).as_posix()
        found = re.search(r"\*\*Recipe\*\*: \[`(recipes/[^`]+\.toml)`\]", card)
        assert found, f"{onnx.with_suffix('.md')} names no recipe"
        if seed:
            assert Path(found.group(1)).stem == seed.group(1)
        else:
            assert load_recipe(ROOT / found.group(1)).ships == shipped
        assert f"- **Weights**: `{shipped}`, sha256 `{sha256(onnx)}`." in card


# ---------------------------------------------------------------- the runner
def test_a_recipe_makes_the_same_policy_twice(tmp_path):
    for out in ("first", "second"):
        assert main(["run", str(TINY), "--out", str(tmp_path / out), "--quiet"]) == 0
    first, second = tmp_path / "first" / "tiny.onnx", tmp_path / "second" / "tiny.onnx"
    assert sha256(first) == sha256(second)
    recipe = load_recipe(TINY)
    ends = [read_counters(segment_folder(tmp_path / "first", k, s)).env_step for k, s in enumerate(recipe.segments, 1)]
    assert ends == [160, 240]
    second_log = (segment_folder(tmp_path / "first", 2, recipe.segments[1]) / "metrics.jsonl").read_text()
    note = next(json.loads(line)["note"] for line in second_log.splitlines() if '"resume"' in line)
    assert "its saved replay buffer is not used (a refill)" in note

    # Cut off after its first segment, the recipe goes on from there to the same policy.
    cut = tmp_path / "cut"
    shutil.copytree(segment_folder(tmp_path / "first", 1, recipe.segments[0]), segment_folder(cut, 1, recipe.segments[0]))
    (segment_folder(cut, 2, recipe.segments[1])).mkdir()  # a segment cut off before its first checkpoint
    (segment_folder(cut, 2, recipe.segments[1]) / "metrics.jsonl").write_text("{}\n")
    assert main(["run", str(TINY), "--out", str(cut), "--quiet"]) == 0
    assert sha256(cut / "tiny.onnx") == sha256(first)


def test_a_segment_with_a_checkpoint_short_of_its_end_resumes_from_it(tmp_path):
    recipe = load_recipe(TINY)
    first, second = (segment_folder(tmp_path, k, s) for k, s in enumerate(recipe.segments, 1))
    calls = []

    def stand_in(config, runs, show_progress=True, load_replay=True):
        calls.append((config.schedule.total_steps, runs[0].out_dir, runs[0].resume, load_replay))
        raise KeyboardInterrupt  # cut off

    for folder, step in ((first, 160), (second, 200)):  # the first finished, the second cut off at 200
        folder.mkdir(parents=True)
        (folder / "state.json").write_text(json.dumps({"format": 1, "counters": {"env_step": step}}))
    with pytest.raises(KeyboardInterrupt):
        run_recipe(recipe, tmp_path, stand_in, note=lambda text: None)
    assert calls == [(240, second, second, True)]


def test_a_runs_seed_replaces_every_segments_seed(tmp_path):
    recipe = load_recipe(TINY)
    seeds = []

    def stand_in(config, runs, show_progress=True, load_replay=True):
        seeds.append(config.run.seed)
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_recipe(recipe, tmp_path / "new", stand_in, seed=7, note=lambda text: None)
    first = segment_folder(tmp_path / "half", 1, recipe.segments[0])  # the first segment finished
    first.mkdir(parents=True)
    (first / "state.json").write_text(json.dumps({"format": 1, "counters": {"env_step": 160}}))
    with pytest.raises(KeyboardInterrupt):
        run_recipe(recipe, tmp_path / "half", stand_in, seed=7, note=lambda text: None)
    assert seeds == [7, 7]


def test_a_later_segment_starts_from_the_previous_ones_best_when_told(tmp_path):
    recipe_file = tmp_path / "best.toml"
    recipe_file.write_text(TINY.read_text().replace('refill = true', 'start = "best"'))
    recipe = load_recipe(recipe_file)
    calls = []

    def stand_in(config, runs, show_progress=True, load_replay=True):
        calls.append((runs[0].out_dir.name, runs[0].resume))
        raise KeyboardInterrupt

    first = segment_folder(tmp_path / "out", 1, recipe.segments[0])
    first.mkdir(parents=True)
    (first / "state.json").write_text(json.dumps({"format": 1, "counters": {"env_step": 160}}))
    with pytest.raises(KeyboardInterrupt):
        run_recipe(recipe, tmp_path / "out", stand_in, note=lambda text: None)
    assert calls == [("2-small", first / "best")]


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (('steps = 240', 'steps = 100'), "'steps' 100 must lie past the previous segment's end, 160"),
        (('hidden = 16', 'hidden = 16\nlearning_rate = 1e-3'), "'learning_rate' belongs in 'learner', not 'network'"),
        (('num_envs = 4', 'num_envs = 4\ntotal_steps = 9'), "give the segment's end as 'steps'"),
        (('refill = true', 'refill = true\ncolour = "red"'), "unknown key 'colour'"),
        (('[segment.learner]\nbatch_size', '[segment.learner]\nkappa = 10.0\nbatch_size'), "'kappa' was retired"),
    ],
)
def test_a_malformed_recipe_is_refused_naming_the_segment_and_key(tmp_path, change, message):
    path = tmp_path / "bad.toml"
    text = TINY.read_text()
    assert change[0] in text
    path.write_text(text.replace(change[0], change[1], 1))
    with pytest.raises(RecipeError, match=re.escape(message)):
        load_recipe(path)


# ---------------------------------------------------------------- recipes that extend another
def write_base_and_extension(folder: Path, extension: str) -> Path:
    """TINY as base.toml in `folder` and `extension` as its sub/extension.toml; the extension's path."""
    (folder / "sub").mkdir(parents=True, exist_ok=True)
    (folder / "base.toml").write_text(TINY.read_text())
    (folder / "sub" / "extension.toml").write_text(extension)
    return folder / "sub" / "extension.toml"


def test_an_extension_is_its_bases_segments_with_its_fields_in_every_one(tmp_path):
    path = write_base_and_extension(tmp_path, 'extends = "../base.toml"\nships = "exported/other.onnx"\n'
                                              "[network]\nhidden = 8\nheads = 1\n[learner]\nlearning_rate = 3e-3\n")
    base, recipe = load_recipe(tmp_path / "base.toml"), load_recipe(path)
    assert (recipe.ships, recipe.ships_from) == ("exported/other.onnx", base.ships_from)
    assert [(s.name, s.start, s.refill) for s in recipe.segments] == [(s.name, s.start, s.refill) for s in base.segments]
    for ours, theirs in zip(recipe.segments, base.segments):
        # the extension's learning rate holds over the base's second segment's own 1e-4
        assert ours.config == theirs.config.replace(hidden=8, heads=1, learning_rate=3e-3)


@pytest.mark.parametrize(
    ("extension", "message"),
    [
        ('extends = "../absent.toml"\nships = "exported/x.onnx"\n', "'extends' names"),
        ('extends = "extension.toml"\nships = "exported/x.onnx"\n', "'extends' makes a loop"),
        ('extends = "../base.toml"\nships = "exported/x.onnx"\n[[segment]]\nname = "a"\nsteps = 9\n',
         "unknown key 'segment'"),
        ('extends = "../base.toml"\nships = "exported/x.onnx"\n[schedule]\ntotal_steps = 9\n',
         "schedule.total_steps cannot change"),
        ('extends = "../base.toml"\nships = "exported/x.onnx"\n[network]\nheads = 3\n', "in segment 1 (curriculum)"),
    ],
)
def test_a_bad_extension_is_refused_naming_the_file_and_key(tmp_path, extension, message):
    with pytest.raises(RecipeError, match=re.escape(message)):
        load_recipe(write_base_and_extension(tmp_path, extension))


def test_run_of_a_missing_recipe_is_one_error_line(tmp_path, capsys):
    assert main(["run", str(tmp_path / "absent.toml"), "--out", str(tmp_path / "out")]) == 2
    assert capsys.readouterr().err.startswith("Error: ")


# ---------------------------------------------------------------- recipes that continue a start
FINE_TUNE = ROOT / "tests" / "data" / "tiny-fine-tune.toml"


@pytest.fixture(scope="module")
def tiny_start(tmp_path_factory):
    """TINY's first segment (160 steps) as a checkpoint folder, a snapshot folder and an exported policy."""
    from training.checkpoint import load_network, save_snapshot

    folder = tmp_path_factory.mktemp("start")
    assert main(["run", str(TINY), "--out", str(folder / "run"), "--segments", "1", "--quiet"]) == 0
    checkpoint = segment_folder(folder / "run", 1, load_recipe(TINY).segments[0])
    model, config, counters = load_network(checkpoint)
    save_snapshot(folder / "snapshot", config, model, counters)
    assert main(["export", str(checkpoint), "-o", str(folder / "start.onnx")]) == 0
    return {"checkpoint": checkpoint, "snapshot": folder / "snapshot", "policy": folder / "start.onnx"}


@pytest.mark.parametrize("kind", ["checkpoint", "snapshot", "policy"])
def test_a_fine_tune_continues_a_checkpoint_a_snapshot_or_a_policy_at_its_step(tmp_path, tiny_start, kind):
    from training.checkpoint import read_config
    from training.lab.start import read_start

    out = tmp_path / "out"
    assert main(["run", str(FINE_TUNE), "--start", str(tiny_start[kind]), "--out", str(out), "--quiet"]) == 0
    recipe = load_recipe(FINE_TUNE)
    assert [read_counters(segment_folder(out, k, s)).env_step for k, s in enumerate(recipe.segments, 1)] == [200, 240]
    record = read_start(out)
    assert (record["kind"], record["env_step"]) == (kind, 160)
    # the start's network (TINY's H = 16, L = 1, h = 2), not the recipe's defaults (H = 64)
    network = read_config(segment_folder(out, 2, recipe.segments[1])).network
    assert (network.model, network.hidden, network.layers, network.heads) == ("terl", 16, 1, 2)
    assert read_config(segment_folder(out, 2, recipe.segments[1])).data.reward_scale == 1.0  # the start's, TINY's
    assert (out / "tiny.onnx").is_file()
    # run again: finished, the same start found in place
    assert main(["run", str(FINE_TUNE), "--start", str(tiny_start[kind]), "--out", str(out), "--quiet"]) == 0


def test_a_checkpoint_that_kept_its_model_alone_starts_as_a_snapshot(tmp_path, tiny_start):
    from training.lab.start import start_kind

    kept = tmp_path / "best"  # scripts/keep-cells.py keeps a finished cell's best/ as model, config and state
    kept.mkdir()
    for name in ("model.safetensors", "config.json", "state.json"):
        shutil.copyfile(tiny_start["checkpoint"] / name, kept / name)
    assert (start_kind(tiny_start["checkpoint"]), start_kind(kept)) == ("checkpoint", "snapshot")


def test_seeds_trained_together_each_continue_their_own_start(tmp_path, tiny_start):
    for seed in (1, 2):
        shutil.copyfile(tiny_start["policy"], tmp_path / f"start-{seed}.onnx")
    start = str(tmp_path / "start-{seed}.onnx")
    assert main(["run", str(FINE_TUNE), "--start", start, "--seeds", "1,2", "--out", str(tmp_path / "out"), "--quiet"]) == 0
    from training.lab.start import read_start

    assert [read_start(tmp_path / "out" / f"seed-{seed}")["source"] for seed in (1, 2)] == [
        str(tmp_path / "start-1.onnx"), str(tmp_path / "start-2.onnx")]
    assert all((tmp_path / "out" / f"seed-{seed}" / "tiny.onnx").is_file() for seed in (1, 2))


def test_seeds_from_one_checkpoint_are_runs_of_their_own_and_its_own_seed_goes_on_as_it_was(tmp_path, tiny_start):
    from training.checkpoint import read_config
    from training.lab.start import read_start

    own = read_config(tiny_start["checkpoint"]).run.seed
    other = own + 1
    out = tmp_path / "out"
    assert main(["run", str(FINE_TUNE), "--start", str(tiny_start["checkpoint"]), "--seeds", f"{own},{other}",
                 "--out", str(out), "--quiet"]) == 0
    states = [json.loads((out / f"seed-{seed}" / "0-start" / "state.json").read_text()) for seed in (own, other)]
    assert states[0]["rng"] == json.loads((tiny_start["checkpoint"] / "state.json").read_text())["rng"]
    assert states[1]["rng"] != states[0]["rng"]
    assert [read_start(out / f"seed-{seed}")["generators"] for seed in (own, other)] == ["the start's", f"seeded by {other}"]
    recipe = load_recipe(FINE_TUNE)
    last = [(out / f"seed-{seed}" / f"{len(recipe.segments)}-{recipe.segments[-1].name}" / "model.safetensors").read_bytes()
            for seed in (own, other)]
    assert last[0] != last[1]  # not the same run twice


def test_a_recipe_may_bring_its_starts_values_to_its_own_reward_scale(tmp_path, tiny_start):
    from safetensors.torch import load_file

    from training.checkpoint import read_config
    from training.lab.start import VALUE_LAYER, read_start

    recipe = tmp_path / "rescaled.toml"  # TINY's start learnt at x 1; its values brought to x 1/20
    recipe.write_text(f'extends = "{FINE_TUNE}"\nships = "exported/tiny.onnx"\nstart_reward_scale = 0.05\n')
    out = tmp_path / "out"
    assert main(["run", str(recipe), "--start", str(tiny_start["checkpoint"]), "--out", str(out), "--quiet",
                 "--segments", "1"]) == 0
    assert read_start(out)["values_rescaled"] == pytest.approx(0.05)
    for name in ("model.safetensors", "target.safetensors"):
        before, after = load_file(str(tiny_start["checkpoint"] / name)), load_file(str(out / "0-start" / name))
        for key in before:
            expected = before[key] * 0.05 if key in VALUE_LAYER else before[key]
            assert after[key].equal(expected), (name, key)
    assert read_config(out / "0-start").data.reward_scale == 0.05
    assert read_config(segment_folder(out, 1, load_recipe(recipe).segments[0])).data.reward_scale == 0.05
    # the same command again finds the start in place; the start at another scale is refused
    assert main(["run", str(recipe), "--start", str(tiny_start["checkpoint"]), "--out", str(out), "--quiet",
                 "--segments", "1"]) == 0
    recipe.write_text(recipe.read_text().replace("0.05", "0.1"))
    assert main(["run", str(recipe), "--start", str(tiny_start["checkpoint"]), "--out", str(out), "--quiet"]) == 2


@pytest.mark.parametrize("value", ["0", "-1.0", "true", '"x"'])
def test_a_start_reward_scale_that_is_not_a_scale_is_refused(tmp_path, value):
    recipe = tmp_path / "rescaled.toml"
    recipe.write_text(f'extends = "{FINE_TUNE}"\nships = "exported/x.onnx"\nstart_reward_scale = {value}\n')
    with pytest.raises(RecipeError, match="'start_reward_scale' must be a reward scale above 0"):
        load_recipe(recipe)


def test_a_start_at_another_step_moves_every_step_of_the_recipe():
    recipe = load_recipe(ROOT / "recipes" / "scale-fine-tune.toml")
    assert recipe.from_step == 200_000
    moved = recipe.shifted(7_000_000)
    lengths = [s.config.schedule.total_steps - recipe.from_step for s in recipe.segments]
    assert [s.config.schedule.total_steps - 7_000_000 for s in moved.segments] == lengths == [
        100_000, 150_000, 175_000, 215_000, 245_000]
    # the curriculum's last stage from the start on; the team mix's step size falls over its own 30 k steps
    assert moved.segments[0].config.schedule.curriculum_steps == 7_000_000
    assert moved.segments[-1].config.learner.decay_start == 7_215_000
    assert [s.config.replace(total_steps=t.config.schedule.total_steps, curriculum_steps=t.config.schedule.curriculum_steps,
                             decay_start=t.config.learner.decay_start) for s, t in zip(moved.segments, recipe.segments)] == [
        t.config for t in recipe.segments]


def test_the_default_recipe_is_the_paper_curriculum_then_the_scale_fine_tune():
    default = load_recipe(ROOT / "recipes" / "terl.toml")
    paper = load_recipe(ROOT / "recipes" / "terl-paper.toml")
    fine_tune = load_recipe(ROOT / "recipes" / "scale-fine-tune.toml")
    assert default.segments[0] == paper.segments[0]
    # it ends at 200 k, where the fine-tune's steps count from, and its rewards at 1/20 carry
    assert paper.segments[0].config.data.reward_scale == 0.05
    assert default.segments[1:] == tuple(
        dataclasses.replace(segment, config=segment.config.replace(reward_scale=0.05)) for segment in fine_tune.segments)
    assert (default.from_step, default.ships) == (None, "exported/terl.onnx")
    extended = load_recipe(ROOT / "recipes" / "terl-default.toml")
    assert extended.segments == default.segments


def test_the_authors_fine_tune_starts_from_each_seeds_last_model():
    recipe = load_recipe(ROOT / "recipes" / "terl-authors-scale.toml")
    assert recipe.segments == load_recipe(ROOT / "recipes" / "scale-fine-tune.toml").segments
    for seed in (1, 2, 3):
        from training.lab.start import seed_start

        start = seed_start(recipe.start, seed)
        assert start == ROOT / "exported" / "comparison" / f"terl-authors-seed-{seed}.onnx" and start.is_file()


def test_every_comparison_method_goes_through_the_fine_tune_from_its_own_seeds_with_its_network(tmp_path):
    from training.lab.start import place_start, seed_start
    from training.checkpoint import load_network

    fine_tune = load_recipe(ROOT / "recipes" / "scale-fine-tune.toml")
    methods = sorted((ROOT / "recipes" / "comparison").glob("*.toml"))
    scale = sorted((ROOT / "recipes" / "comparison-scale").glob("*.toml"))
    assert [path.name for path in scale] == [path.name for path in methods]
    for path in scale:
        recipe = load_recipe(path)
        assert recipe.segments == fine_tune.segments, path
        assert recipe.ships == f"exported/comparison-scale/{path.stem}.onnx"
        starts = [seed_start(recipe.start, seed) for seed in (1, 2, 3)]
        assert starts == [ROOT / "exported" / "comparison" / f"{path.stem}-seed-{seed}.onnx" for seed in (1, 2, 3)]
        # the start's network and reward scale carry (the 1 M protocol's x 1/20); nothing else changes
        counters = place_start(starts[0], tmp_path / path.stem, seed=1)
        _, start_config, _ = load_network(tmp_path / path.stem)
        shifted = recipe.shifted(counters.env_step)
        carried = shifted.carrying(start_config)
        method = load_recipe(methods[scale.index(path)]).segments[0].config
        for ours, theirs in zip(carried.segments, shifted.segments):
            assert (ours.config.network, ours.config.data.reward_scale) == (method.network, 0.05), path
            assert ours.config.replace(**{name: theirs.config.value(name) for name in CARRIED_FIELDS}) == theirs.config


def test_a_recipe_that_continues_a_start_refuses_to_run_without_one_and_others_refuse_one(tmp_path, tiny_start):
    with pytest.raises(RecipeError, match=re.escape("continues a start (from_step 160): give --start")):
        run_recipe(load_recipe(FINE_TUNE), tmp_path / "a", lambda *a, **k: {}, note=lambda text: None)
    with pytest.raises(RecipeError, match="starts from nothing .no from_step., so it takes no --start"):
        run_recipe(load_recipe(TINY), tmp_path / "b", lambda *a, **k: {}, note=lambda text: None,
                   start=str(tiny_start["policy"]))
    with pytest.raises(RecipeError, match="not a checkpoint, snapshot or .onnx policy"):
        run_recipe(load_recipe(FINE_TUNE), tmp_path / "c", lambda *a, **k: {}, note=lambda text: None,
                   start=str(tmp_path))


def test_a_run_folder_keeps_its_start(tmp_path, tiny_start):
    out = tmp_path / "out"
    assert main(["run", str(FINE_TUNE), "--start", str(tiny_start["policy"]), "--out", str(out), "--segments", "1",
                 "--quiet"]) == 0
    with pytest.raises(RecipeError, match="holds another start"):
        run_recipe(load_recipe(FINE_TUNE), out, lambda *a, **k: {}, note=lambda text: None,
                   start=str(tiny_start["checkpoint"]))


def test_seeds_trained_together_start_from_one_step(tmp_path, tiny_start):
    from training.checkpoint import load_network, save_snapshot

    model, config, counters = load_network(tiny_start["checkpoint"])
    counters.env_step = 120
    save_snapshot(tmp_path / "start-2", config, model, counters)
    shutil.copytree(tiny_start["snapshot"], tmp_path / "start-1")
    with pytest.raises(RecipeError, match="seeds trained together start from one step"):
        run_recipe(load_recipe(FINE_TUNE), tmp_path / "out", lambda *a, **k: {}, seeds=[1, 2], note=lambda text: None,
                   start=str(tmp_path / "start-{seed}"))


@pytest.mark.parametrize(
    ("chain", "message"),
    [
        ('[[chain]]\nrecipe = "base.toml"\n[[chain]]\nrecipe = "base.toml"\n', "starts from nothing (no from_step)"),
        ('[[chain]]\nrecipe = "base.toml"\nsegments = 3\n', "'segments' must be 1-2"),
        ('[[chain]]\nrecipe = "absent.toml"\n', "'recipe' names"),
        ('[[chain]]\nsegments = 1\n', "a link is a table"),
        ('[[chain]]\nrecipe = "base.toml"\nsegments = 1\n[[chain]]\nrecipe = "rescaled.toml"\n',
         "brings its start's values to another scale (start_reward_scale), which a chain does not do"),
    ],
)
def test_a_bad_chain_is_refused_naming_the_link(tmp_path, chain, message):
    (tmp_path / "base.toml").write_text(TINY.read_text())
    (tmp_path / "rescaled.toml").write_text(f'extends = "{FINE_TUNE}"\nships = "exported/x.onnx"\nstart_reward_scale = 1.0\n')
    (tmp_path / "chain.toml").write_text('ships = "exported/x.onnx"\n' + chain)
    with pytest.raises(RecipeError, match=re.escape(message)):
        load_recipe(tmp_path / "chain.toml")


def test_a_chain_shifts_its_later_links_to_where_the_first_ends_carrying_its_network_and_reward_scale(tmp_path):
    (tmp_path / "base.toml").write_text(TINY.read_text().replace("learning_starts = 40", "learning_starts = 40\nreward_scale = 0.05"))
    shutil.copyfile(FINE_TUNE, tmp_path / "fine.toml")
    (tmp_path / "fine.toml").write_text(FINE_TUNE.read_text().replace("from_step = 160", "from_step = 100"))
    (tmp_path / "chain.toml").write_text('ships = "exported/x.onnx"\n[[chain]]\nrecipe = "base.toml"\nsegments = 1\n'
                                         '[[chain]]\nrecipe = "fine.toml"\n')
    recipe = load_recipe(tmp_path / "chain.toml")
    assert [(s.name, s.config.schedule.total_steps) for s in recipe.segments] == [
        ("curriculum", 160), ("small", 260), ("mix", 300)]
    assert recipe.segments[2].config.learner.decay_start == 260
    assert {s.config.network.hidden for s in recipe.segments} == {16}  # the first link's network
    assert {s.config.data.reward_scale for s in recipe.segments} == {0.05}  # and the scale its values are in


def test_a_grid_of_a_recipe_with_a_start_field_ships_cards_that_name_each_seeds_start(tmp_path, tiny_start):
    recipes = tmp_path / "recipes"
    recipes.mkdir()
    shutil.copyfile(FINE_TUNE, recipes / "fine.toml")
    for seed in (1, 2):
        shutil.copyfile(tiny_start["policy"], tmp_path / f"start-{seed}.onnx")
    (recipes / "tiny-ft.toml").write_text('extends = "fine.toml"\nships = "exported/tiny-ft.onnx"\n'
                                          'start = "../start-{seed}.onnx"\n')
    assert main(["grid", str(recipes / "tiny-ft.toml"), "--seeds", "1,2", "--out", str(tmp_path / "runs"),
                 "--seeds-per-process", "2", "--ship", str(tmp_path / "exported")]) == 0
    card = (tmp_path / "exported" / "tiny-ft.md").read_text()
    assert "2 seeds of 240 environment steps" in card  # the start's 160 and the fine-tune's 80
    assert f"seed 2: `{tmp_path / 'start-2.onnx'}` (a policy, `terl` H = 16, L = 1, 160 steps)" in card
    from training.export import read_metadata

    assert read_metadata(tmp_path / "exported" / "tiny-ft-seed-1.onnx")["terl.training_steps"] == "240"
