"""`python -m training`'s subcommands, one module each. A subcommand imports what trains,
exports or loads networks (torch, onnx) inside its function, so that `--help` answers without
importing torch (tests/test_imports.py)."""
