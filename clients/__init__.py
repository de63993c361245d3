"""Python client and the `bentray` command-line interface."""
