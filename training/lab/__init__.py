"""training's lab, on top of its core: recipes and their runner (recipe, start), grids of
methods x seeds (grid, grid_ray) and their shipping (ship, card), learning curves (curves,
snapshot_curves), value checks (values) and the loop's speed (throughput).

Only the command line (training.cli) imports it; the core never does (pyproject.toml).
"""
