"""The suite's domains: one module per domain, each with its `default_config()` (the configs
themselves live in `envs_mjx.config`, which imports neither JAX nor MuJoCo)."""

from envs_mjx.domains.ant import Ant
from envs_mjx.domains.cartpole import CartPole
from envs_mjx.domains.half_cheetah import HalfCheetah
from envs_mjx.domains.incline import GeomOnIncline
from envs_mjx.domains.inverted_pendulum import InvertedPendulum

__all__ = ["Ant", "CartPole", "GeomOnIncline", "HalfCheetah", "InvertedPendulum"]
