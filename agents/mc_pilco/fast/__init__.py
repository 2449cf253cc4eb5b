"""Fast particle rollouts of :class:`~mcpilco.agents.mc_pilco.loss.MCPilcoLoss`, beside the
algorithm: the loss itself only rolls out eagerly; the trainer picks a fast rollout here,
which is checked against the eager one before the optimisation uses it.

* :mod:`~mcpilco.agents.mc_pilco.fast.base`: the chained time step over the parts' public
  step protocols, :class:`ShardedRollout` (one autograd node per rollout, split by
  particles over threads);
* :mod:`~mcpilco.agents.mc_pilco.fast.chained`: :class:`TorchRollout`, the chained rollout
  in PyTorch ops;
* :mod:`~mcpilco.agents.mc_pilco.fast.native`: :class:`NativeRollout`, the same maths in a
  C++ extension (its sources beside it);
* :mod:`~mcpilco.agents.mc_pilco.fast.select`: the backends by name and
  :func:`use_fast_rollout`;
* :mod:`~mcpilco.agents.mc_pilco.fast.check`: :func:`check_against_eager`.

This package imports only the parts' public names; no part imports it.
"""

from mcpilco.agents.mc_pilco.fast.base import (
    MIN_SHARD_PARTICLES,
    PARAM_NAMES,
    RolloutFunction,
    ShardedRollout,
    default_shards,
    unsupported_reason,
)
from mcpilco.agents.mc_pilco.fast.chained import TorchRollout
from mcpilco.agents.mc_pilco.fast.check import (
    COMPILE_CHECK_HORIZON,
    COMPILE_CHECK_RTOL,
    check_against_eager,
)
from mcpilco.agents.mc_pilco.fast.native import (
    NativeRollout,
    build_error,
    cpp_compiler,
    cpp_compiler_names,
    native_unsupported_reason,
)
from mcpilco.agents.mc_pilco.fast.select import (
    AUTO_ORDER,
    BACKENDS,
    CHAINED_BACKENDS,
    ChainedBackend,
    FastRollout,
    choose_backend,
    use_fast_rollout,
)

__all__ = [
    "AUTO_ORDER",
    "BACKENDS",
    "CHAINED_BACKENDS",
    "COMPILE_CHECK_HORIZON",
    "COMPILE_CHECK_RTOL",
    "ChainedBackend",
    "FastRollout",
    "MIN_SHARD_PARTICLES",
    "NativeRollout",
    "PARAM_NAMES",
    "RolloutFunction",
    "ShardedRollout",
    "TorchRollout",
    "build_error",
    "check_against_eager",
    "choose_backend",
    "cpp_compiler",
    "cpp_compiler_names",
    "default_shards",
    "native_unsupported_reason",
    "unsupported_reason",
    "use_fast_rollout",
]
