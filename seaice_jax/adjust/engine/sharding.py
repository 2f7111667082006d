"""Monte Carlo realizations over all local JAX devices (``jax.sharding``).

:func:`sharded_vmap` is ``jax.vmap(function)`` whose mapped (leading) axis is laid out over a one-axis
:class:`~jax.sharding.Mesh` of the local devices (:class:`~jax.sharding.NamedSharding`), each device running the
vmapped function on its own share of the realizations (``jax.shard_map``; the other arguments are replicated). The
devices never communicate: a vmapped ``while_loop`` (a Gauss-Newton solver) stops on each device when its own lanes
have converged. Every lane computes what it computes unsharded: the results equal those of the unsharded program on
each device's share (a different batch size may round differently in the last bit, and an iterative solver then
stops elsewhere within its tolerance, sharded or not).

On a CPU, ``XLA_FLAGS=--xla_force_host_platform_device_count=N`` (set before JAX is imported) makes N host devices;
give the XLA CPU runtime more threads than devices (``NPROC``): the devices run their batched LAPACK kernels at
once, and on too few threads they wait on each other for ever (the deadlock of :mod:`seaice_jax._small_linalg`). On a
GPU machine the same code spreads the realizations over its GPUs.
"""

import functools
from collections.abc import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

AXIS = "realizations"
"""The mesh axis the realizations are split along."""


def realization_mesh(devices: Sequence | None = None) -> Mesh:
    """A one-axis mesh (:data:`AXIS`) over ``devices`` (default: every local device)."""
    return Mesh(np.array(jax.local_devices() if devices is None else list(devices)), (AXIS,))


def _pad(leaf, count: int):
    """``leaf`` with its leading axis padded to ``count`` by repeating its last realization."""
    leaf = jnp.asarray(leaf)
    if count == leaf.shape[0]:
        return leaf
    return jnp.concatenate([leaf, jnp.repeat(leaf[-1:], count - leaf.shape[0], axis=0)])


def sharded_vmap(function: Callable, in_axes: int | None | tuple = 0,
                 devices: Sequence | None = None) -> Callable:
    """``jax.vmap(function, in_axes)``, jitted, with the realizations split over ``devices`` (default: every local
    device, :func:`realization_mesh`).

    Args:
        function: one realization: arrays (pytrees) in, arrays (pytrees) out.
        in_axes: per positional argument, ``0`` (a pytree whose leaves carry a leading realizations axis) or
            ``None`` (shared by every realization); one value for all arguments.

    Returns:
        A function of the same arguments returning the stacked results ``(realizations, ...)``, as ``jax.vmap``
        would. The realizations are padded to a multiple of the device count (the last one repeated) and the
        padding dropped from the results.

    Raises:
        ValueError: an ``in_axes`` other than 0 or None, or mapped arguments of different lengths.
    """
    mesh = realization_mesh(devices)
    split, shared = NamedSharding(mesh, PartitionSpec(AXIS)), NamedSharding(mesh, PartitionSpec())
    count = mesh.devices.size

    @functools.cache
    def solver(axes: tuple):
        specs = tuple(PartitionSpec(AXIS) if axis == 0 else PartitionSpec() for axis in axes)
        return jax.jit(jax.shard_map(jax.vmap(function, in_axes=axes), mesh=mesh, in_specs=specs,
                                     out_specs=PartitionSpec(AXIS), check_vma=False))

    def run(*args):
        axes = in_axes if isinstance(in_axes, tuple) else (in_axes,) * len(args)
        if any(axis not in (0, None) for axis in axes) or len(axes) != len(args):
            raise ValueError(f"in_axes must be 0 or None per argument, got {in_axes!r} for {len(args)} arguments")
        lengths = {leaf.shape[0] for arg, axis in zip(args, axes, strict=True) if axis == 0
                   for leaf in jax.tree.leaves(arg)}
        if len(lengths) != 1:
            raise ValueError(f"the mapped arguments must share one number of realizations, got {sorted(lengths)}")
        runs = lengths.pop()
        padded = -(-runs // count) * count
        placed = [jax.tree.map(lambda leaf: jax.device_put(_pad(leaf, padded), split), arg) if axis == 0
                  else jax.tree.map(lambda leaf: jax.device_put(leaf, shared), arg)
                  for arg, axis in zip(args, axes, strict=True)]
        return jax.tree.map(lambda leaf: leaf[:runs], solver(tuple(axes))(*placed))

    return run
