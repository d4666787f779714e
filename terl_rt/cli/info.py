"""`terl-rt info`: a policy's metadata and its contract check."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import click

from terl_rt.cli.options import BadInput, json_option
from terl_rt.policy.checks import PASS
from terl_rt.policy.onnx_policy import check_contract


@click.command()
@click.argument("policy", type=str)
@json_option
def info(policy: str, as_json: bool) -> None:
    """Show an ONNX policy's metadata, inputs, outputs and the check against the
    exported-policy contract (the terl-rt repository's docs/policy.md section 3). Exit status 2 when the contract
    refuses the model (the report is printed first).

    \b
    Examples:
      terl-rt info my-policy.onnx
      terl-rt info my-policy.onnx --json
    """
    path = Path(policy)
    report = check_contract(path)  # FileNotFoundError / ContractError for unreadable files
    sha256 = hashlib.sha256(path.read_bytes()).hexdigest()
    if as_json:
        click.echo(json.dumps({
            "path": str(path),
            "sha256": sha256,
            "ok": report.ok,
            "metadata": dict(report.metadata),
            "inputs": [{"name": t.name, "type": t.describe()} for t in report.inputs],
            "outputs": [{"name": t.name, "type": t.describe()} for t in report.outputs],
            "checks": [{"name": c.name, "status": c.status, "detail": c.detail} for c in report.checks],
        }))
    else:
        passed = sum(check.status == PASS for check in report.checks)
        verdict = "meets the contract" if report.ok else f"refused by the contract: {report.failures[0].detail}"
        click.echo(f"policy   {path}: {verdict} ({passed} of {len(report.checks)} checks pass)")
        click.echo(f"sha256   {sha256}")
        click.echo("metadata")
        for key, value in sorted(report.metadata.items()):
            click.echo(f"  {key} = {value}")
        click.echo("inputs")
        for tensor in report.inputs:
            click.echo(f"  {tensor.name}: {tensor.describe()}")
        click.echo("outputs")
        for tensor in report.outputs:
            click.echo(f"  {tensor.name}: {tensor.describe()}")
        click.echo("contract")
        click.echo("\n".join(f"  {line}" for line in report.format().splitlines()))
    if not report.ok:
        raise BadInput(f"{path}: the contract refuses this policy: {report.failures[0].detail}")
