"""`python -m training export`: a checkpoint as an ONNX policy."""

from __future__ import annotations

import re
from pathlib import Path

import click

from terl_rt.policy.contract import META_METHOD, META_SEED
from training.cli.options import output_option

METHOD_NAME = re.compile(r"[a-z0-9][a-z0-9._-]*")
"""What --method takes: a recipe stem's form (terl, terl-authors, terl-no-re)."""


@click.command("export")
@click.argument("checkpoint", type=click.Path(path_type=Path), metavar="CHECKPOINT_DIR_OR_FILE")
@output_option("FILE.onnx")
@click.option("--method", default=None, metavar="NAME",
              help="Name the policy's method (metadata terl.method, as a grid's policies are named after their "
                   "recipe): `terl-rt report` compares policies by method, and seeds of one method over seeds.")
@click.option("--seed", type=click.IntRange(min=0), default=None,
              help="Name the policy's training seed (metadata terl.seed) [default: the seed of its training config].")
def export_command(checkpoint: Path, output: Path, method: str | None, seed: int | None) -> None:
    """Export a checkpoint (a run folder, its best/ snapshot, or one of their files) as a
    contract-v1 ONNX policy, parity-checked against torch. Given an exported policy (.onnx)
    instead, write it again with the current exporter's graph, from the weights inside it
    (for a shipped policy whose checkpoint is not shipped), checked to compute what it did.

    \b
    Examples:
      python -m training export runs/terl -o runs/terl.onnx
      python -m training export exported/terl.onnx -o runs/terl-reexported.onnx
      # the shipped default beside the 1 M seeds (method terl, seeds 1-3) in one report:
      python -m training export exported/terl.onnx --method terl-default -o runs/three/terl-default.onnx
    """
    from training.checkpoint import export_checkpoint
    from training.export import read_metadata, reexport_onnx
    from training.onnx_weights import WeightsNotFound

    if method is not None and not METHOD_NAME.fullmatch(method):
        raise click.BadParameter(f"{method!r} is no method name (lower-case letters, digits, '.', '_' and '-', "
                                 "as a recipe's file name)", param_hint="--method")
    tags = {META_METHOD: method} if method is not None else {}
    if seed is not None:
        tags[META_SEED] = str(seed)
    if checkpoint.suffix == ".onnx":
        if not checkpoint.is_file():
            raise click.BadParameter(f"no policy file at {checkpoint}", param_hint="CHECKPOINT_DIR_OR_FILE")
        try:
            path = reexport_onnx(checkpoint, output, tags)
        except WeightsNotFound as error:
            raise click.BadParameter(str(error), param_hint="CHECKPOINT_DIR_OR_FILE") from None
    else:
        path = export_checkpoint(checkpoint, output, tags)
    metadata = read_metadata(path)
    named = "".join(f", {key} {metadata[key]}" for key in (META_METHOD, META_SEED) if key in metadata)
    click.echo(
        f"{path}: {metadata['terl.model']} H={metadata['terl.hidden']} L={metadata['terl.layers']} "
        f"h={metadata['terl.heads']}, {metadata['terl.training_steps']} training steps on "
        f"{metadata['terl.trained_on']}{named}; torch-onnxruntime parity checked"
    )
