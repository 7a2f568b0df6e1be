"""The one place where biped_switch patches a dependency.

brax 0.14.2 calls `jax.device_put_replicated` (PPO, SAC, APG, training/pmap.py). jax >= 0.10 no
longer exports it at the top level, but `jax._src.api.device_put_replicated` still exists in 0.10.2
(Python 3.11 here) and 0.11.2 (the GPU host), so we re-export it. Remove once brax stops calling it.
"""

import jax

if not hasattr(jax, "device_put_replicated"):
    from jax._src.api import device_put_replicated as _dpr

    jax.device_put_replicated = _dpr
