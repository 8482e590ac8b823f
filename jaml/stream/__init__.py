"""The suite's learning loop (paper §2.1): PPO frame stream, replay, learner updates, alignment.

    from jaml import stream
    cfg = stream.for_env("CartPole", "VAE_rpl", epochs=200, replay_slots=1024)
    s = stream.build(cfg)
    state = s.init(jax.random.PRNGKey(0))
    state, metrics = s.run_epochs(state, 10)       # 10 epochs, metrics stacked [10]
    report = s.evaluate(state, key, pi_rand_key)   # alignment errors on π_rand / π_curr

`jaml suite` (jaml.stream.run) wraps this with a run directory and resumable checkpoints.
"""

from jaml.stream.collect import Episodes, rollout
from jaml.stream.config import POLICIES, StreamConfig, for_env
from jaml.stream.loop import Stream, StreamState, build
from jaml.stream.ppo import PPO, PPOConfig, PPOState, random_policy
from jaml.stream.replay import Columns, Replay

__all__ = [
    "POLICIES",
    "PPO",
    "Columns",
    "Episodes",
    "PPOConfig",
    "PPOState",
    "Replay",
    "Stream",
    "StreamConfig",
    "StreamState",
    "build",
    "for_env",
    "random_policy",
    "rollout",
]
