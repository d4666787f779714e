"""How to install an optional extra of terl-rt, said once for every hint that needs it."""


def install_hint(extra: str) -> str:
    """The command that installs `extra` from PyPI, and its form in a checkout."""
    return f"pip install 'terl-rt[{extra}]' (in a terl-rt checkout: pip install -e '.[{extra}]')"
