"""The evaluation suite's domains: MJCF models stepped in MJX, drawn by a JAX software renderer."""
