"""`python -m training export`: a checkpoint as an ONNX policy."""

from __future__ import annotations

from pathlib import Path

import click

from training.checkpoint import export_checkpoint
from training.cli.options import output_option
from training.export import read_metadata, reexport_onnx
from training.onnx_weights import WeightsNotFound


@click.command("export")
@click.argument("checkpoint", type=click.Path(path_type=Path), metavar="CHECKPOINT_DIR_OR_FILE")
@output_option("FILE.onnx")
def export_command(checkpoint: Path, output: Path) -> None:
    """Export a checkpoint (a run folder, its best/ snapshot, or one of their files) as a
    contract-v1 ONNX policy, parity-checked against torch. Given an exported policy (.onnx)
    instead, write it again with the current exporter's graph, from the weights inside it
    (for a shipped policy whose checkpoint is not shipped), checked to compute what it did.

    \b
    Examples:
      python -m training export runs/terl -o runs/terl.onnx
      python -m training export exported/terl.onnx -o runs/terl-reexported.onnx
    """
    if checkpoint.suffix == ".onnx":
        if not checkpoint.is_file():
            raise click.BadParameter(f"no policy file at {checkpoint}", param_hint="CHECKPOINT_DIR_OR_FILE")
        try:
            path = reexport_onnx(checkpoint, output)
        except WeightsNotFound as error:
            raise click.BadParameter(str(error), param_hint="CHECKPOINT_DIR_OR_FILE") from None
    else:
        path = export_checkpoint(checkpoint, output)
    metadata = read_metadata(path)
    click.echo(
        f"{path}: {metadata['terl.model']} H={metadata['terl.hidden']} L={metadata['terl.layers']} "
        f"h={metadata['terl.heads']}, {metadata['terl.training_steps']} training steps on "
        f"{metadata['terl.trained_on']}; torch-onnxruntime parity checked"
    )
