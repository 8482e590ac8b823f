"""The configs of jaml's parts, free of JAX: relations (`Config`), learners (their configs and
the learner registry), the stream (`StreamConfig`, per-domain defaults, `RunConfig`) and the
reading of run records written by older code (`records`). The command line's parser reads
these; the packages that run them (`jaml.relations`, `jaml.learners`, `jaml.stream`) import JAX
and re-export the configs."""
