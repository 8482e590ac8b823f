"""Peers measured side by side with jaml: our own re-statements of the reference stacks."""
