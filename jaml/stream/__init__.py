"""The suite's learning loop (paper §2.1): PPO frame stream, replay, learner updates, alignment.

    from jaml import stream
    cfg = stream.for_env("CartPole", "VAE_rpl", {"epochs": 200, "replay.slots": 1024})
    s = stream.build(cfg)
    state = s.init(jax.random.PRNGKey(0))
    state, metrics = stream.run_epochs(s, state, 10)   # 10 epochs, metrics stacked [10]
    report = stream.evaluate(s, state, key, pi_rand_key)   # alignment on π_rand / π_curr

    # Six seeds as one program (vmapped; split across the local devices on GPU/TPU):
    states = stream.stack_runs([s.init(jax.random.PRNGKey(i)) for i in range(6)])
    states, metrics = stream.run_stacked_epochs(s, states, 10)   # metrics [10, 6]

A Stream owns what is compiled for it (`Stream.jit`): build one per config and keep it while it
serves; its programs go when it does.

`jaml suite` (jaml.stream.run) drives this over run directories with resumable checkpoints
(jaml.stream.rundir); `jaml.stream.run.run_many` trains several seeds together, each in its own
directory.
"""

from jaml.configs.stream import (
    POLICIES,
    EvalConfig,
    PenaltyConfig,
    PPOConfig,
    ReplayConfig,
    RunConfig,
    StreamConfig,
    for_env,
    resolve,
)
from jaml.stream.analysis import evaluate
from jaml.stream.collect import Episodes, rollout
from jaml.stream.executor import (
    run_epochs,
    run_stacked_epochs,
    runs_mesh,
    stack_runs,
    unstack_runs,
)
from jaml.stream.loop import Stream, StreamState, build
from jaml.stream.ppo import PPO, PPOState, random_policy
from jaml.stream.replay import Columns, Replay

__all__ = [
    "POLICIES",
    "PPO",
    "Columns",
    "Episodes",
    "EvalConfig",
    "PPOConfig",
    "PPOState",
    "PenaltyConfig",
    "Replay",
    "ReplayConfig",
    "RunConfig",
    "Stream",
    "StreamConfig",
    "StreamState",
    "build",
    "evaluate",
    "for_env",
    "random_policy",
    "resolve",
    "rollout",
    "run_epochs",
    "run_stacked_epochs",
    "runs_mesh",
    "stack_runs",
    "unstack_runs",
]
