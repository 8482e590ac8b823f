"""The evaluation suite's domains: MJCF models stepped in MJX, rendered by a JAX software renderer."""
