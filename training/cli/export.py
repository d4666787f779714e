"""`python -m training export`: a checkpoint as an ONNX policy."""

from __future__ import annotations

from pathlib import Path

import click

from training.checkpoint import export_checkpoint
from training.cli.options import output_option
from training.export import read_metadata


@click.command("export")
@click.argument("checkpoint", type=click.Path(path_type=Path), metavar="CHECKPOINT_DIR_OR_FILE")
@output_option("FILE.onnx")
def export_command(checkpoint: Path, output: Path) -> None:
    """Export a checkpoint (a run folder, its best/ snapshot, or one of their files) as a
    contract-v1 ONNX policy, parity-checked against torch."""
    path = export_checkpoint(checkpoint, output)
    metadata = read_metadata(path)
    click.echo(
        f"{path}: {metadata['terl.model']} H={metadata['terl.hidden']} L={metadata['terl.layers']} "
        f"h={metadata['terl.heads']}, {metadata['terl.training_steps']} training steps on "
        f"{metadata['terl.trained_on']}; torch-onnxruntime parity checked"
    )
